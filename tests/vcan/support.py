"""Helpers for the tests on a real SocketCAN bus (vcan0): bench commands as forked children,
can-utils as subprocesses, the interface's link state, and reading what a run left.

Every ``bench`` command runs as ``bench.cli.main(argv)`` in a child forked from the test
process, which the console script ``bench`` calls the same way: the child starts with every
module already imported. In the VM (tools/vcan-vm) Python runs about 20x slower than on the
host, and a fresh interpreter importing the bench would cost tens of seconds per command.
"""

from __future__ import annotations

import faulthandler
import importlib
import json
import multiprocessing
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

CHANNEL = "vcan0"
VM_HINT = "run them in a VM: tools/vcan-vm . .venv/bin/python -m pytest -m vcan tests/vcan"
REQUIRED = os.environ.get("BENCH_VCAN_REQUIRED") == "1"
"""Set by .ci/run in the VM: a missing prerequisite fails the test instead of skipping it."""


def need(reason: str | None) -> None:
    """Skip (or, when REQUIRED, fail) the calling test when ``reason`` says what is missing."""
    if reason is not None:
        (pytest.fail if REQUIRED else pytest.skip)(reason)


def socketcan_missing(channel: str = CHANNEL) -> str | None:
    """Why this kernel cannot carry the tests (no SocketCAN, no ``channel``, link down), or
    None when a raw CAN socket binds to ``channel`` and the link is up."""
    if not hasattr(socket, "AF_CAN") or not hasattr(socket, "CAN_RAW"):
        return f"no SocketCAN on {sys.platform}"
    try:
        sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as exc:
        return f"this kernel has no SocketCAN ({exc.strerror})"
    try:
        sock.bind((channel,))
        if sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR):
            return f"{channel} is down"
    except OSError as exc:
        return f"no {channel} interface ({exc.strerror})"
    finally:
        sock.close()
    return None


def net_admin_missing() -> str | None:
    """Why ``ip link set`` would fail here (it needs root / CAP_NET_ADMIN), or None."""
    if shutil.which("ip") is None:
        return "no ip command (iproute2)"
    if os.geteuid() != 0:
        return "setting a link down and up needs root (CAP_NET_ADMIN)"
    return None


def tool_missing(*names: str) -> str | None:
    missing = [n for n in names if shutil.which(n) is None]
    return f"no {', '.join(missing)} (apt-get install can-utils)" if missing else None


# -- bench commands in forked children -------------------------------------------------------
def _child(argv: list[str], out: str, env: dict[str, str]) -> None:
    fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115 - the child's own
    sys.stderr = sys.stdout
    os.environ.update(env)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # a stack dump on demand
    from bench.cli import main

    code = main(argv)
    sys.stdout.flush()
    os._exit(code)


class Bench:
    """``bench ARGV`` in a forked child; stdout and stderr go to ``out``."""

    def __init__(self, argv: Sequence[str], out: Path, env: dict[str, str] | None = None) -> None:
        self.argv = [str(a) for a in argv]
        self.out = out
        ctx = multiprocessing.get_context("fork")
        self.proc = ctx.Process(target=_child, args=(self.argv, str(out), env or {}), daemon=True)
        self.proc.start()

    @property
    def pid(self) -> int:
        assert self.proc.pid is not None
        return self.proc.pid

    def text(self) -> str:
        return self.out.read_text(errors="replace") if self.out.exists() else ""

    def wait_for(self, needle: str, timeout: float = 120.0) -> None:
        """Until ``needle`` appears in the output (fails when the child ends first)."""
        deadline = time.monotonic() + timeout
        while needle not in self.text():
            if not self.proc.is_alive():
                raise AssertionError(f"bench {' '.join(self.argv)} ended: {self.text()}")
            if time.monotonic() > deadline:
                raise AssertionError(f"no {needle!r} from bench {' '.join(self.argv)}")
            time.sleep(0.05)

    def received(self) -> int:
        """Frames received (and dropped by the kernel) by the last status line of a run."""
        lines = re.findall(r" (\d+) frames .* drop \d+(?: kdrop (\d+))?", self.text())
        return int(lines[-1][0]) + int(lines[-1][1] or 0) if lines else 0

    def wait_received(self, n: int, timeout: float = 300.0) -> None:
        """Until the run's status line says it has had ``n`` frames: a run in the VM may be
        seconds behind the bus, and stopping it drops what its socket still holds."""
        deadline = time.monotonic() + timeout
        while self.received() < n:
            if not self.proc.is_alive() or time.monotonic() > deadline:
                raise AssertionError(f"{self.received()} of {n} frames: {self.text()}")
            time.sleep(0.2)

    def wait_settled(self, quiet_s: float = 3.0, timeout: float = 300.0) -> None:
        """Until the run's count has not moved for ``quiet_s`` (the bus is idle by then)."""
        deadline = time.monotonic() + timeout
        seen, since = self.received(), time.monotonic()
        while time.monotonic() - since < quiet_s:
            if not self.proc.is_alive() or time.monotonic() > deadline:
                raise AssertionError(f"run did not settle: {self.text()}")
            time.sleep(0.2)
            now = self.received()
            if now != seen:
                seen, since = now, time.monotonic()

    def signal(self, sig: int) -> None:
        os.kill(self.pid, sig)

    def join(self, timeout: float = 600.0) -> int:
        self.proc.join(timeout)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5)
            raise AssertionError(f"bench {' '.join(self.argv)} did not end: {self.text()}")
        assert self.proc.exitcode is not None
        return self.proc.exitcode

    def stop(self, timeout: float = 600.0) -> int:
        """Ctrl-C, as an operator ends a run; the exit code."""
        if self.proc.is_alive():
            self.signal(signal.SIGINT)
        return self.join(timeout)


PRELOAD = (
    "bench.cli",
    "bench.live.runner",
    "bench.live.setup",
    "bench.mcaplog.info",
    "bench.mcaplog.reader",
    "bench.mcaplog.sink",
    "bench.replay.run",
    "bench.records.columns",
    "bench.sinks.tables",
    "pyarrow.compute",
    "pyarrow.csv",
    "pyarrow.parquet",
    "devices.emulator",
    "devices.files",
    "devices.socketcan_rx",
    "devices.writers",
)


def preload() -> None:
    """Import, in the test process, what the forked bench commands will need, so that each
    child starts with it (and not with a minute of imports on the VM's slow CPU)."""
    for name in PRELOAD:
        importlib.import_module(name)
    from bench.cli import build_parser

    build_parser()  # imports every command module


def bench_main(*argv: Any) -> int:
    """``bench ARGV`` in this process (a replay, an export: nothing that must run beside)."""
    from bench.cli import main

    return main([str(a) for a in argv])


def start_run(
    tmp: Path, name: str, *extra: Any, env: dict[str, str] | None = None
) -> tuple[Bench, Path, Path]:
    """``bench run -i socketcan -c vcan0`` with a CSV and an MCAP, once it is listening."""
    csv, mcap = tmp / f"{name}.csv", tmp / f"{name}.mcap"
    argv = ["run", "-i", "socketcan", "-c", CHANNEL, "--csv", csv, "--mcap", mcap]
    argv += ["--duration", "600", "--status-every", "0.5"]
    run = Bench([*argv, *extra], tmp / f"{name}.out", env)
    run.wait_for("bench: logging to")  # printed once the source's socket is bound
    return run, csv, mcap


def play(tmp: Path, name: str, scenario: Path) -> Bench:
    """``bench emulate SCENARIO -i socketcan -c vcan0``: the virtual board on the bus."""
    return Bench(["emulate", scenario, "-i", "socketcan", "-c", CHANNEL, "-q"], tmp / f"{name}.out")


def frames_sent(board: Bench) -> tuple[int, int, int]:
    """(sent, of, send errors) from the board's closing line."""
    m = re.search(r"done: (\d+) of (\d+) frames sent(?:, (\d+) send errors)?", board.text())
    assert m, board.text()
    return int(m[1]), int(m[2]), int(m[3] or 0)


# -- can-utils -------------------------------------------------------------------------------
def candump(folder: Path) -> subprocess.Popen[bytes]:
    """``candump -l vcan0`` in ``folder`` (it names its own file there)."""
    # -D: keep recording across a link down/up; -r: a receive buffer it cannot overrun
    argv = ["candump", "-l", "-D", "-r", str(8 << 20), CHANNEL]
    proc = subprocess.Popen(argv, cwd=folder, stderr=subprocess.DEVNULL)
    time.sleep(0.5)  # it binds within a few ms on the host, longer in the VM
    return proc


def stop_candump(proc: subprocess.Popen[bytes], folder: Path) -> Path:
    proc.send_signal(signal.SIGINT)
    proc.wait(30)
    logs = sorted(folder.glob("candump-*.log"))
    assert len(logs) == 1, logs
    return logs[0]


def cangen(*args: str) -> subprocess.Popen[bytes]:
    """``cangen vcan0 ARGS`` started; wait() on it."""
    return subprocess.Popen(["cangen", CHANNEL, *args])


def first_frame(timeout: float = 120.0) -> None:
    """Wait until a frame is seen on vcan0 (a board has started playing)."""
    with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as sock:
        sock.bind((CHANNEL,))
        sock.settimeout(timeout)
        sock.recv(16)


def set_link(state: str) -> None:
    subprocess.run(["ip", "link", "set", CHANNEL, state], check=True, timeout=30)


# -- what a run left -------------------------------------------------------------------------
def log_info(path: Path) -> dict[str, Any]:
    """``bench log info --json`` of an MCAP."""
    from bench.mcaplog.info import log_info as info

    return json.loads(json.dumps(info(path)))


def read_log_frames(path: Path) -> np.ndarray:
    """Every frame of a candump .log or a bench MCAP (FRAME_DTYPE), in file order."""
    if path.suffix == ".mcap":
        from bench.mcaplog.reader import McapLog

        with McapLog(path) as lg:
            return lg.read_frames()[0]
    from devices.formats import open_log

    src = open_log(path)
    try:
        parts = [b.frames for b in src.batches()]
    finally:
        src.close()
    return np.concatenate(parts) if parts else np.zeros(0)


def topic(path: Path, name: str) -> list[dict[str, Any]]:
    from bench.mcaplog.reader import McapLog

    with McapLog(path) as lg:
        return lg.json_topic(name)


def per_id(frames: np.ndarray) -> Counter[int]:
    return Counter(frames["id"].tolist())


def wire(frames: np.ndarray) -> list[tuple[int, int, bytes]]:
    """(id, dlc, payload) per frame: what travelled, without the receive time."""
    return [
        (int(i), int(d), bytes(row[: min(int(d), 8)]))
        for i, d, row in zip(frames["id"], frames["dlc"], frames["data"], strict=True)
    ]


RECEIVE_TIME = "utc"
"""The CSV column of a frame's receive time: when it crossed the bus, so not in an emulator's
file (empty there), and candump's log has it to the microsecond only."""


ODOMETER_AGE = ("gradient_signed_permil", "gradient_sigma_permil", "odometer_suspect", "coasting")
"""The estimator's columns that depend on how old each SPEED_REF reading is at the sample that
applies it, which the bench tells from receive times: a live bus, candump's microseconds and
an emulator's schedule carry the same frames with receive times a little apart, so these
agree closely between them, not bit for bit (a replay of the run's own MCAP agrees exactly)."""


def assert_same_results(a: str, b: str, *ignored: str) -> None:
    """Two result CSVs of the same frames with different receive times: every column but the
    receive time and ``ignored`` identical; the estimator's gradient (ODOMETER_AGE) given at
    the same samples but for a few, and within twice its sigma where both give it."""
    skip = (RECEIVE_TIME, *ignored)
    assert columns_without(a, *skip, *ODOMETER_AGE) == columns_without(b, *skip, *ODOMETER_AGE)
    if "gradient_signed_permil" in ignored:
        return
    ga, gb = (_column(text, "gradient_signed_permil") for text in (a, b))
    assert len(ga) == len(gb)
    agree = np.isfinite(ga) == np.isfinite(gb)
    assert agree.mean() >= 0.9, agree.mean()
    both = np.isfinite(ga) & np.isfinite(gb)
    if both.any():
        sa, sb = (_column(text, "gradient_sigma_permil") for text in (a, b))
        diff = np.abs(ga[both] - gb[both])
        within = diff <= 2.0 * np.maximum(sa[both], sb[both])
        assert within.mean() >= 0.99, (within.mean(), np.quantile(diff, [0.5, 0.99, 1.0]))


def _column(csv_text: str, name: str) -> np.ndarray:
    rows = [line.split(",") for line in csv_text.splitlines()]
    k = rows[0].index(name)
    return np.array([float(r[k]) if r[k] else np.nan for r in rows[1:]])


def columns_without(csv_text: str, *names: str) -> list[list[str]]:
    """The CSV's cells, row by row, without the columns ``names``."""
    rows = [line.split(",") for line in csv_text.splitlines()]
    drop = {rows[0].index(name) for name in names}
    return [[v for k, v in enumerate(r) if k not in drop] for r in rows]


def replay_csv(log: Path, out: Path, *config: Any) -> str:
    extra: Iterable[Any] = ("--config", *config) if config else ()
    assert bench_main("replay", log, "--csv", out, "-q", *extra) == 0
    return out.read_text()
