"""An operator's usual mistakes each end in one clear line (issue 28): a live run that never
received a frame (a channel name typo on the virtual bus looks exactly like that) says so
and exits 1. The wrong interface name and the kernel without CAN are in
tests/test_devices_cli_args.py and tests/test_devices_bus.py; the piped fleet table in
tests/test_fleet.py."""

from __future__ import annotations

import uuid

import pytest

from bench.cli import main


def test_a_live_run_that_receives_nothing_says_so_and_exits_1(
    capsys: pytest.CaptureFixture[str],
) -> None:
    channel = f"typo-{uuid.uuid4().hex[:8]}"  # a virtual channel no one sends on
    code = main(["run", "-i", "virtual", "-c", channel, "--duration", "0.5", "--no-log", "-q"])
    err = capsys.readouterr().err
    assert code == 1
    line = next(ln for ln in err.splitlines() if "no frame received" in ln)
    assert line.startswith("bench: error: no frame received in ")
    assert f"interface=virtual channel={channel}" in line and "channel name" in line


def test_a_live_run_that_receives_frames_is_not_warned(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "--emulate", "demo", "--duration", "0.5", "--no-log", "-q"])
    assert code == 0
    assert "no frame received" not in capsys.readouterr().err


def test_a_run_stopped_by_the_operator_before_any_frame_says_so_but_is_no_error() -> None:
    """SIGTERM 1 s into a run on a silent channel: the line is there (without 'error:'),
    the exit code is the stop's, not 1: the operator ended it, nothing failed."""
    import signal
    import subprocess
    import sys
    import time

    channel = f"quiet-{uuid.uuid4().hex[:8]}"
    cmd = [sys.executable, "-m", "bench", "run", "-i", "virtual", "-c", channel, "--no-log"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stderr is not None
        # the --no-log warning comes after the run's signal handlers are in place (a fixed
        # sleep raced the interpreter's start-up at load: SIGTERM killed it at import)
        head = [proc.stderr.readline()]
        while head[-1] and "--no-log" not in head[-1]:
            head.append(proc.stderr.readline())
        time.sleep(0.5)  # not a bound: the run waits for frames that never come
        proc.send_signal(signal.SIGTERM)
        _, rest = proc.communicate(timeout=60)
        err = "".join(head) + rest
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode in (0, 143), err
    line = next(ln for ln in err.splitlines() if "no frame received" in ln)
    assert line.startswith("bench: no frame received in "), line
    assert "Traceback" not in err
