"""A Foxglove viewer that subscribes and never reads cannot hold a run (issue 27).

Before: such a client kept `bench run --duration 10` alive for minutes, and SIGTERM did not
end it; any viewer that could reach the port could hold a run. The viewer here is
:class:`tests.foxglove_client.StalledClient` (a raw socket on 127.0.0.1 with a 4 KiB
receive buffer that reads nothing after it subscribed); the run must end at its
``--duration`` and on SIGTERM, with a finished MCAP log whose length is the run's. The
limits below are hang guards, never speed bounds.
"""

from __future__ import annotations

import re
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from bench.mcaplog.info import log_info
from tests.foxglove_client import StalledClient
from tests.test_hostile_records import bench

GUARD_S = 180.0


class Lines:
    """A stream's lines as they come (a thread reads it; the test waits for one)."""

    def __init__(self, stream) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.append(line)

    def wait(self, pattern: str, proc: subprocess.Popen[str], after: int = 0) -> re.Match[str]:
        deadline = time.monotonic() + GUARD_S
        while time.monotonic() < deadline:
            for line in self.lines[after:]:
                if m := re.search(pattern, line):
                    return m
            assert proc.poll() is None or self._thread.is_alive(), "".join(self.lines)
            time.sleep(0.05)
        raise AssertionError(f"no line matching {pattern!r}: {''.join(self.lines)}")

    def text(self) -> str:
        self._thread.join(GUARD_S)
        return "".join(self.lines)


def _wait_for_bytes(path: Path, proc: subprocess.Popen[str], size: int) -> None:
    """Until the live log holds ``size`` bytes (a hang guard, not a speed bound)."""
    deadline = time.monotonic() + GUARD_S
    while not (path.exists() and path.stat().st_size >= size):
        assert proc.poll() is None, "the run ended early"
        assert time.monotonic() < deadline, f"{path} never reached {size} bytes"
        time.sleep(0.05)


def _start(tmp_path: Path, duration: str) -> tuple[subprocess.Popen[str], Lines, Lines, Path]:
    sc = tmp_path / "s.toml"
    sc.write_text("duration_s = 600.0\nseed = 2\n")
    log = tmp_path / "run.mcap"
    proc = bench(
        "run", "--emulate", str(sc), "--duration", duration, "--foxglove", "0",
        "--mcap", str(log), "--status-every", "0.2",
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    return proc, Lines(proc.stdout), Lines(proc.stderr), log


@pytest.mark.parametrize("subprotocol", ["foxglove.websocket.v1", "foxglove.sdk.v1"])
def test_a_viewer_that_never_reads_does_not_hold_the_run_past_its_duration(tmp_path, subprotocol):
    proc, _out, err, log = _start(tmp_path, "4")
    viewer = None
    try:
        port = int(err.wait(r"Foxglove live stream on ws://127\.0\.0\.1:(\d+)", proc)[1])
        viewer = StalledClient(port, subprotocol)
        assert viewer.status == "HTTP/1.1 101 Switching Protocols"
        viewer.subscribe("/can/frames")  # and from now on reads nothing
        proc.wait(GUARD_S)  # without the fix: minutes, while the viewer stays connected
    finally:
        if proc.poll() is None:
            proc.kill()
        if viewer is not None:
            viewer.close()
    assert proc.returncode == 0, err.text()
    info = log_info(log)
    assert info["complete"], info
    assert 3.5 <= info["duration_s"] <= 4.5, info["duration_s"]  # the run's 4 s of frames


def test_sigterm_ends_a_run_whose_viewer_never_reads(tmp_path):
    proc, _out, err, log = _start(tmp_path, "600")
    viewer = None
    try:
        port = int(err.wait(r"Foxglove live stream on ws://127\.0\.0\.1:(\d+)", proc)[1])
        viewer = StalledClient(port).subscribe("/can/frames")
        _wait_for_bytes(log, proc, 100_000)  # the run goes on with the viewer stalled
        proc.send_signal(signal.SIGTERM)
        proc.wait(GUARD_S)  # without the fix SIGTERM did not end it
    finally:
        if proc.poll() is None:
            proc.kill()
        if viewer is not None:
            viewer.close()
    assert proc.returncode == 0, err.text()
    info = log_info(log)
    assert info["complete"] and info["frames"] > 0, info
