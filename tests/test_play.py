"""`bench play LOG -i virtual -c CH` (issue 28): every frame of the log onto the bus, in order,
never ahead of its recorded time (scaled by --rate), filtered by --ids and --skip-to,
looped, and stopped by a signal with 128 + its number. A receiver on the same python-can
``virtual`` channel counts what arrived; expectations come from the log itself read with
the bench's opener, not from the player. No wall-time bound: only "not earlier than
recorded", which a player that ignored the timing would break.
"""

from __future__ import annotations

import os
import re
import signal
import threading
import time
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from bench.cli import main
from devices.formats import open_log

SCENARIO = """
description = "bench play: 2 s at 100 Hz"
seed = 3
duration_s = 2.0
sample_rate_hz = 100
initial_speed_mps = 5.0
[[track]]
length_m = 100.0
gradient_permil = 5.0
"""
EARLY_S = 0.002
"""How early a frame may leave: MessageSync does not sleep below 0.1 ms."""


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("play")
    sc = d / "short.toml"
    sc.write_text(SCENARIO)
    out = {}
    for suffix in (".log", ".mcap"):
        path = d / f"short{suffix}"
        assert main(["emulate", str(sc), "--out", str(path), "-q"]) == 0
        out[suffix] = path
    return out


def frames_of(path: Path) -> np.ndarray:
    src = open_log(path)
    try:
        return np.concatenate([b.frames for b in src.batches()])
    finally:
        src.close()


class Receiver:
    """Every message on a virtual channel, with its arrival time (time.time())."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel, ignore_config=True)
        self.messages: list[can.Message] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is not None:
                self.messages.append(msg)

    def close(self) -> list[can.Message]:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:  # drain what is queued
            n = len(self.messages)
            time.sleep(0.2)
            if len(self.messages) == n:
                break
        self._stop.set()
        self._thread.join(5)
        self.bus.shutdown()
        return self.messages


def wire(msgs: list[can.Message]) -> list[tuple[int, bytes]]:
    return [(m.arbitration_id, bytes(m.data)) for m in msgs]


def wire_of(frames: np.ndarray) -> list[tuple[int, bytes]]:
    return [(int(f["id"]), bytes(f["data"][: min(int(f["dlc"]), 8)].tobytes())) for f in frames]


def play(log: Path, *extra: str) -> tuple[int, list[can.Message], float]:
    """(exit code, what arrived, time.time() just before the command started)."""
    channel = f"play-{uuid.uuid4().hex[:8]}"
    rx = Receiver(channel)
    before = time.time()
    try:
        code = main(["play", str(log), "-i", "virtual", "-c", channel, "-q", *extra])
    finally:
        got = rx.close()
    return code, got, before


@pytest.mark.parametrize("suffix", [".log", ".mcap"])
def test_every_frame_in_order_never_ahead_of_its_time(
    logs: dict[str, Path], suffix: str, capsys: pytest.CaptureFixture[str]
) -> None:
    frames = frames_of(logs[suffix])
    assert len(frames) > 500
    code, got, before = play(logs[suffix])
    assert code == 0
    assert wire(got) == wire_of(frames)  # every frame, in the log's order
    recorded = frames["t"] - frames["t"][0]
    arrived = np.array([m.timestamp for m in got]) - before
    assert (arrived >= recorded - EARLY_S).all()
    # nor ahead of the first frame's own time: no late start caught up in a burst
    assert (arrived - arrived[0] >= recorded - 0.05).all()
    out = capsys.readouterr().out
    n = len(frames)
    assert f"bench: done: {n} frames sent of {n} selected ({n} in the log), 0 send errors" in out


def test_rate_scales_the_recorded_timing(logs: dict[str, Path]) -> None:
    frames = frames_of(logs[".mcap"])
    code, got, before = play(logs[".mcap"], "--rate", "4")
    assert code == 0 and len(got) == len(frames)
    arrived = np.array([m.timestamp for m in got]) - before
    assert (arrived >= (frames["t"] - frames["t"][0]) / 4 - EARLY_S).all()


def test_ids_and_skip_to_select_exactly_those_frames(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    frames = frames_of(logs[".log"])
    rel = frames["t"] - frames["t"][0]
    want = frames[(rel >= 1.0) & np.isin(frames["id"], [0x101, 0x180])]
    assert 0 < len(want) < len(frames)
    code, got, _ = play(logs[".log"], "--ids", "101,0x180", "--skip-to", "1")
    assert code == 0
    assert wire(got) == wire_of(want)
    out = capsys.readouterr().out
    before_skip = int((rel < 1.0).sum())
    others = int(((rel >= 1.0) & ~np.isin(frames["id"], [0x101, 0x180])).sum())
    assert (
        f"{len(want)} frames sent of {len(want)} selected ({len(frames)} in the log; "
        f"{before_skip} before --skip-to, {others} of other IDs)"
    ) in out


def test_an_id_range(logs: dict[str, Path]) -> None:
    frames = frames_of(logs[".log"])
    code, got, _ = play(logs[".log"], "--ids", "101-103", "--rate", "50")
    assert code == 0
    assert wire(got) == wire_of(frames[(frames["id"] >= 0x101) & (frames["id"] <= 0x103)])


def _signal_after(n: int, rx_messages: list, sig: int) -> threading.Thread:
    def run() -> None:
        deadline = time.monotonic() + 300
        while len(rx_messages) < n and time.monotonic() < deadline:
            time.sleep(0.02)
        os.kill(os.getpid(), sig)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_loop_until_a_signal_then_exit_128_plus_it(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str], sig: int, code: int
) -> None:
    frames = frames_of(logs[".log"])
    n = len(frames)
    channel = f"play-{uuid.uuid4().hex[:8]}"
    rx = Receiver(channel)
    stopper = _signal_after(n + 50, rx.messages, sig)  # into the second pass
    try:
        argv = ["play", str(logs[".log"]), "-i", "virtual", "-c", channel, "-q", "--loop"]
        got_code = main([*argv, "--rate", "20"])
    finally:
        stopper.join(10)
        got = rx.close()
    assert got_code == code
    assert wire(got[: 2 * n]) == (wire_of(frames) * 2)[: len(got[: 2 * n])]  # pass after pass
    out = capsys.readouterr().out
    m = re.search(
        rf"bench: stopped \({signal.Signals(sig).name}\) at [\d.]+ s: (\d+) frames sent", out
    )
    assert m, out
    assert int(m[1]) == len(got) and len(got) > n  # every frame sent arrived
    assert re.search(r", pass \d+,", out) and ", pass 1," not in out
    assert signal.getsignal(signal.SIGTERM) is not None  # the handlers were put back


def test_a_capture_without_receive_times_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sc = tmp_path / "s.toml"
    sc.write_text(SCENARIO)
    raw = tmp_path / "raw.bin"
    assert main(["emulate", str(sc), "--out", str(raw), "-q"]) == 0
    assert main(["play", str(raw), "-i", "virtual", "-c", "never-opened"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("bench: error: ") and "no receive times" in err and "\n" not in err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--ids", "xyz"], "--ids: 'xyz' is not a hex CAN ID"),
        (["--ids", "7ff-100"], "not a CAN ID range"),
        (["--skip-to", "99"], "none of its"),
    ],
)
def test_bad_selections_are_one_line(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    assert main(["play", str(logs[".log"]), "-i", "virtual", "-c", "x", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err


def test_status_line_says_time_frames_sent_and_in_the_log_and_errors(
    logs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    frames = frames_of(logs[".log"])
    channel = f"play-{uuid.uuid4().hex[:8]}"
    rx = Receiver(channel)
    try:
        argv = ["play", str(logs[".log"]), "-i", "virtual", "-c", channel, "--status-every", "0.1"]
        assert main(argv) == 0
    finally:
        rx.close()
    n = len(frames)
    lines = capsys.readouterr().err.splitlines()
    pattern = rf" *([\d.]+)/2\.0 s  (\d+) of {n} frames sent \({n} in the log\)  errors 0"
    shown = [re.fullmatch(pattern, line) for line in lines]
    assert shown and all(shown), lines
    sent = [int(m[2]) for m in shown if m]
    times = [float(m[1]) for m in shown if m]
    assert sent == sorted(sent) and times == sorted(times) and sent[-1] <= n


def test_an_interrupt_kept_on_the_player_ends_play_before_the_next_frame(
    logs: dict[str, Path],
) -> None:
    """The play command's signal handler keeps its Stopped on the player as well as raising
    it: a raise that lands in a finaliser is lost, and a looping play would never end."""
    from bench.replay.bus_player import BusPlayer, Selection, count_log

    path = logs[".log"]
    bus = can.Bus(interface="virtual", channel=f"play-{uuid.uuid4().hex[:8]}")
    try:
        player = BusPlayer(path, bus, count_log(path, Selection()), rate=20.0, loop=True)
        player.interrupt = KeyboardInterrupt("kept")
        with pytest.raises(KeyboardInterrupt, match="kept"):
            player.play()
    finally:
        bus.shutdown()
    assert player.sent == 0 and player.passes == 1
