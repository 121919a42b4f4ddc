"""The engine process (bench/engine/): a live TUI session run in a child process.

The screen's rows must be the run's rows bit for bit (checked against a replay of the log the
engine wrote), operator actions must reach the run, and however the run ends -- ``q``, the
engine killed, SIGTERM to the engine, the parent killed -- every MCAP file is finished or the
failure is said, and no process is left behind.
"""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bench.config import Config
from bench.engine.child import RowTap
from bench.engine.client import EngineSession, start_engine
from bench.engine.plans import BoardPlan, EnginePlan
from bench.errors import BenchError
from bench.live.view import ResultRing
from bench.pipeline.steps import StepOutput
from bench.records.results import RESULT_DTYPE
from tests.helpers import until

ROOT = Path(__file__).resolve().parent.parent
CONFIG = Config(sample_rate_hz=200)


def rows(start: int, count: int) -> np.ndarray:
    r = np.zeros(count, dtype=RESULT_DTYPE)
    r["n"] = np.arange(start, start + count)
    return r


def board_plan(tmp_path: Path, seconds: float = 30.0, speed: float = 1.0) -> BoardPlan:
    return BoardPlan(
        config=CONFIG,
        scenario={"duration_s": seconds, "sample_rate_hz": 200, "seed": 5},
        speed=speed,
        mcap=tmp_path / "first.mcap",
        log_dir=tmp_path / "logs",
    )


def complete(path: Path) -> bool:
    from bench.mcaplog.reader import McapLog

    with McapLog(path) as log:
        return bool(log.complete)


def alive(pid: int) -> bool:
    """A process that exists and is not a zombie waiting to be reaped."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    return "State:\tZ" not in status


@pytest.fixture
def engine(tmp_path: Path) -> Any:
    sessions: list[EngineSession] = []

    def start(plan: EnginePlan) -> EngineSession:
        session = start_engine(plan)
        sessions.append(session)
        return session

    yield start
    for s in sessions:
        s.stop()
        assert not alive(s.pid)


# -- the pieces --------------------------------------------------------------------------------
def test_ring_keeps_the_newest_rows_in_order_across_the_wrap() -> None:
    ring = ResultRing(size=10)
    pushed = [rows(0, 4), rows(4, 5), rows(9, 7), rows(16, 1), rows(17, 25)]
    for i, part in enumerate(pushed):
        ring.extend(part)
        so_far = np.concatenate(pushed[: i + 1])["n"]
        assert ring.last(100)["n"].tolist() == so_far[-10:].tolist()
        assert ring.last(3)["n"].tolist() == so_far[-3:].tolist()
    assert len(ring) == 10 and len(ring.last(0)) == 0


def test_tap_hands_over_each_row_once_and_only_the_newest_when_behind() -> None:
    tap = RowTap(limit=6)
    assert tap.take()[0].dtype == RESULT_DTYPE and len(tap.take()[0]) == 0
    tap.write(StepOutput(results=rows(0, 2)))
    tap.write(StepOutput(results=rows(2, 0)))
    tap.write(StepOutput(results=rows(2, 3)))
    assert tap.take()[0]["n"].tolist() == [0, 1, 2, 3, 4]
    for k in range(5, 20, 3):  # the screen fell behind: it only ever shows the newest
        tap.write(StepOutput(results=rows(k, 3)))
    assert tap.take()[0]["n"].tolist() == [14, 15, 16, 17, 18, 19]
    got, restart = tap.take()
    assert len(got) == 0 and not restart


def test_tap_replaces_previews_by_the_full_rows() -> None:
    """While the estimator's kernel is prepared the screen gets preview rows; the first
    full rows (from the first sample on) replace them, and the screen is told so once."""
    tap = RowTap(limit=100)
    tap.preview(StepOutput(results=rows(0, 3)))
    assert tap.take()[0]["n"].tolist() == [0, 1, 2]  # shown as they come
    tap.preview(StepOutput(results=rows(3, 2)))  # not taken yet when the full rows come
    tap.write(StepOutput(results=rows(0, 5)))
    tap.write(StepOutput(results=rows(5, 1)))
    got, restart = tap.take()
    assert restart and got["n"].tolist() == [0, 1, 2, 3, 4, 5]
    tap.write(StepOutput(results=rows(6, 1)))
    assert tap.take()[0]["n"].tolist() == [6] and not tap.take()[1]


# -- a live run in the engine ------------------------------------------------------------------
def test_screen_rows_are_the_logged_run_bit_for_bit(tmp_path: Path, engine: Any) -> None:
    """Snapshots bring only new rows; put together here they must be what the pipeline
    computes from the frames in the engine's log (replayed on its own)."""
    from bench.replay.run import replay
    from devices.formats import open_log

    plan = board_plan(tmp_path, seconds=6.0, speed=3.0)
    session = engine(plan)
    seen = 0
    while seen < 300:  # many small snapshots, as the screen takes them
        seen = len(session.snapshot(last=50_000).results)
        time.sleep(0.05)
    drained = session.request("drain", 30.0)
    shown = session.snapshot(last=50_000)
    session.stop()
    assert drained["sent"] == session.report.frames_received > 0
    expected = replay(open_log(plan.mcap), CONFIG).results
    assert 0 < len(shown.results) <= len(expected)
    assert shown.results.tobytes() == expected[: len(shown.results)].tobytes()
    assert session.recorder.files == [plan.mcap] and complete(plan.mcap)


def test_operator_actions_reach_the_run_through_the_app(tmp_path: Path, engine: Any) -> None:
    from bench.mcaplog.recorded import read_events
    from bench.tui.app import BenchApp, next_tolerance

    session = engine(board_plan(tmp_path))
    app = BenchApp(session, poll_hz=8)

    async def wait(cond: Callable[[], bool], what: str) -> None:
        deadline = time.monotonic() + 20
        while not cond():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            await asyncio.sleep(0.05)

    async def drive() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await wait(lambda: app.snapshots_applied >= 2, "the screen to show the run")
            assert app.last_snapshot is not None and len(app.last_snapshot.results)
            await pilot.press("plus")
            assert session.tolerance() == next_tolerance(CONFIG.tolerance_permil, 1)
            await pilot.press("r")  # stop recording: the engine finishes the first file
            await wait(lambda: not session.recorder.active, "the recording to stop")
            await pilot.press("r")  # a new file in log_dir
            await wait(lambda: session.recorder.active, "the recording to start")
            await pilot.press("m")
            await pilot.press("q")
            await wait(lambda: not app.is_running, "the app to quit")

    asyncio.run(drive())
    assert session.stopped and session.runner.error is None
    first, second = session.recorder.files
    assert first == tmp_path / "first.mcap" and second.parent == tmp_path / "logs"
    assert complete(first) and complete(second)
    assert any("tolerance set to" in str(e) for e in read_events(first))
    assert any("operator mark 1" in str(e) for e in read_events(second))


class FailingPlan(EnginePlan):
    def open_setup(self) -> Any:
        raise BenchError("cannot open can bus interface=nowhere: no such adapter")


def test_a_build_error_in_the_engine_is_raised_here_as_it_was(tmp_path: Path) -> None:
    with pytest.raises(BenchError, match=r"^cannot open can bus interface=nowhere"):
        start_engine(FailingPlan(config=CONFIG))


def test_log_folder_unusable_is_the_commands_one_line_error(tmp_path: Path) -> None:
    import argparse

    from bench.engine.plans import LivePlan

    blocker = tmp_path / "logs"
    blocker.write_text("a file where the log folder should be")
    args = argparse.Namespace(emulate="demo", mcap=str(blocker / "run.mcap"), no_log=False)
    with pytest.raises(BenchError, match="cannot create log folder"):
        start_engine(LivePlan(config=CONFIG, args=args))


# -- however it ends ---------------------------------------------------------------------------
def test_engine_killed_the_screen_says_so_and_nothing_hangs(tmp_path: Path, engine: Any) -> None:
    session = engine(board_plan(tmp_path))
    until(lambda: session.snapshot(last=1).frames_received > 100, what="frames")
    os.kill(session.pid, signal.SIGKILL)
    until(lambda: session.runner.error is not None, what="the loss to be noticed")
    assert "ended unexpectedly" in session.runner.error
    snap = session.snapshot(last=10)  # the screen keeps its last picture
    assert not snap.running and snap.error == session.runner.error and len(snap.results)
    session.mark("after the end")
    session.set_tolerance(3.0)
    with pytest.raises(RuntimeError):
        session.recorder.start()
    session.stop()
    assert session.stopped and not alive(session.pid)


def test_sigterm_to_the_engine_finishes_the_log_reports_and_exits(
    tmp_path: Path, engine: Any
) -> None:
    """SIGTERM (a system shutdown, an operator's kill) stops the run on its own: the engine
    must not wait for a request then."""
    plan = board_plan(tmp_path)
    session = engine(plan)
    until(lambda: session.snapshot(last=1).frames_received > 100, what="frames")
    os.kill(session.pid, signal.SIGTERM)
    until(lambda: not alive(session.pid), what="the engine to exit by itself")
    assert not session.snapshot(last=1).running
    session.stop()
    assert session.report is not None and session.report.frames_received > 100
    assert session.runner.error is None and complete(plan.mcap)


@pytest.mark.parametrize("end", ["SIGKILL", "exit"])
def test_parent_gone_the_engine_finishes_the_log_and_exits(tmp_path: Path, end: str) -> None:
    """The parent killed (the pipe closes) or leaving without stopping the session (Python's
    exit terminates daemon children, then waits for them): the log is finished either way
    and nothing waits forever."""
    mcap = tmp_path / "orphan.mcap"
    leave = "os.kill(os.getpid(), signal.SIGKILL)" if end == "SIGKILL" else "sys.exit(0)"
    script = f"""
import os, signal, sys, time
from pathlib import Path
from bench.config import Config
from bench.engine.client import start_engine
from bench.engine.plans import BoardPlan
plan = BoardPlan(config=Config(sample_rate_hz=200), mcap=Path({str(mcap)!r}),
                 scenario={{"duration_s": 60.0, "sample_rate_hz": 200, "seed": 5}})
session = start_engine(plan)
while session.snapshot(last=1).frames_received < 200:
    time.sleep(0.05)
print(session.pid, flush=True)
{leave}
"""
    proc = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == (-signal.SIGKILL if end == "SIGKILL" else 0), proc.stderr
    pid = int(proc.stdout.split()[0])
    until(lambda: not alive(pid), timeout=30, what="the engine to exit")
    assert complete(mcap)
