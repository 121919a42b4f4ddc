"""A first start explains itself (issue 28): while numba compiles the estimator's kernel the
screen shows the reference method live and the estimator being prepared; then everything
received meanwhile goes through the full pipeline, so the log holds the full rows from the
first frame, bit for bit what a run with a ready kernel (or the replay) computes.

The kernel is compiled once per test process (conftest); a warm-up that waits on an event
stands in for numba here, so these tests control when it is "ready".
"""

from __future__ import annotations

import io
import threading

import numpy as np
from rich.console import Console

from bench.config import Config
from bench.live.runner import LiveRunner
from bench.live.session import Session
from bench.pipeline.steps import Pipeline, StepOutput
from bench.pipeline.warmup import KernelWarmUp, WarmUpStatus
from bench.records.events import EventKind, concat_events
from bench.sinks.base import RecordingStatus, Sink
from bench.tui.app import BenchApp
from bench.tui.panels.recording import recording_table
from devices.base import SourceBatch
from protocol.layout import STATUS_SELFTEST
from tests.helpers import until
from tests.test_tui_support import ListSource, make_frames, screen_text, settled_snapshot


def stream() -> np.ndarray:
    """Clean, then ch2 flags SELFTEST for 0.5 s (votes fail, the estimator excludes ch2:
    an EXCLUDED event only the full pipeline gives), then clean again."""
    return np.concatenate(
        [
            make_frames(300),
            make_frames(100, start=300, status=(0, STATUS_SELFTEST, 0)),
            make_frames(400, start=400),
        ]
    )


class Recorder(Sink):
    """A sink keeping every step, and how many result rows it had when each mark came."""

    def __init__(self) -> None:
        self.steps: list[StepOutput] = []
        self.marks: list[tuple[str, int]] = []
        self.previews = 0

    def write(self, step: StepOutput) -> None:
        self.steps.append(step)

    def mark(self, t: float, text: str) -> None:
        self.marks.append((text, sum(len(s.results) for s in self.steps)))

    def results(self) -> np.ndarray:
        return np.concatenate([s.results for s in self.steps if len(s.results)])

    def events(self) -> np.ndarray:
        return concat_events([s.events for s in self.steps])


def expected(frames: np.ndarray, split: int, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """The same frames through a pipeline with its kernel ready, the tolerance changed after
    frame ``split``: what the log must hold."""
    pipe = Pipeline(Config())
    steps = [pipe.process(SourceBatch(frames[:split]))]
    pipe.tolerance_permil = tolerance
    steps += [pipe.process(SourceBatch(frames[split:])), pipe.finish()]
    res = np.concatenate([s.results for s in steps if len(s.results)])
    return res, concat_events([s.events for s in steps])


def test_the_log_gets_the_full_rows_of_everything_received_while_the_kernel_was_prepared() -> None:
    frames = stream()
    split = int(np.flatnonzero(frames["t"] > frames["t"][0] + 1.75)[0])  # inside the fault
    gate = threading.Event()
    warm = KernelWarmUp(work=gate.wait).start()
    source = ListSource(frames[:split], chunk=32)
    sink = Recorder()
    runner = LiveRunner(source, Config(), [sink], warm_up=warm)
    runner.start()
    held = lambda: getattr(runner.snapshot(last=0).warmup, "held_frames", None)  # noqa: E731
    try:
        until(lambda: held() == split)
        snap = runner.snapshot()
        # the screen: the reference method live, the estimator pending, nothing logged yet
        assert isinstance(snap.warmup, WarmUpStatus) and snap.warmup.held_frames == split
        assert "preparing the estimator" in snap.warmup.headline()
        assert len(snap.results) > 300
        assert np.isfinite(snap.results["gradient"][:300]).all()  # the reference's values
        assert np.isnan(snap.results["gradient_signed"]).all()  # the estimator's: pending
        kinds = {kind for _, kind, _ in snap.events}
        assert EventKind.VOTE_FAIL in kinds and EventKind.EXCLUDED not in kinds
        assert sink.steps == []
        runner.set_tolerance(2.0)  # applies from the next frame on, in the log too
        runner.mark("during the warm-up")
        assert sink.marks == []
        gate.set()  # the kernel is ready
        until(lambda: runner.snapshot(last=1).warmup is None)
        source.feed(frames[split:])
        until(lambda: runner.pipeline.seq == len(frames))
    finally:
        gate.set()
        runner.stop()
    want_res, want_ev = expected(frames, split, 2.0)
    got = sink.results()
    assert got.tobytes() == want_res.tobytes()  # every row full, bit for bit
    got_ev = sink.events()
    got_ev = got_ev[got_ev["kind"] != EventKind.MARK]
    assert got_ev.tobytes() == want_ev.tobytes()
    assert EventKind.EXCLUDED in got_ev["kind"]
    rows_before_split = int(np.count_nonzero(want_res["seq"] < split))
    assert sink.marks[0][0] == "tolerance set to 2 permil"
    assert sink.marks[1] == ("during the warm-up", sink.marks[0][1])
    assert rows_before_split - 2 <= sink.marks[1][1] <= rows_before_split  # where it was made
    # the screen's rows are the full ones now, estimator included, and its events once each
    snap = runner.snapshot()
    assert snap.results.tobytes() == want_res.tobytes()
    assert sum(1 for _, kind, _ in snap.events if kind == EventKind.EXCLUDED) == int(
        np.count_nonzero(want_ev["kind"] == EventKind.EXCLUDED)
    )
    vote_fails = [e for e in snap.events if e[1] == EventKind.VOTE_FAIL]
    assert len(vote_fails) == len(set(vote_fails))  # the preview's not shown twice


def test_quitting_while_the_kernel_is_prepared_still_logs_every_frame() -> None:
    frames = make_frames(200)
    gate = threading.Event()
    warm = KernelWarmUp(work=lambda: gate.wait(0.5)).start()  # ready in half a second
    sink = Recorder()
    runner = LiveRunner(ListSource(frames, chunk=50), Config(), [sink], warm_up=warm)
    runner.start()
    until(lambda: runner.pipeline.seq == len(frames))
    runner.stop()
    assert sum(len(s.frames) for s in sink.steps) == len(frames)
    assert np.isfinite(sink.results()["gradient_signed"]).any()


def test_the_hold_is_bounded_and_what_it_cannot_keep_is_counted_and_logged_as_dropped() -> None:
    """A kernel that takes too long must cost the log counted frames, not the machine's
    memory: beyond the bound the frames are dropped (the screen's preview still sees
    them), the run's drop counter and one DROPPED event say how many."""
    frames = stream()
    split = int(np.flatnonzero(frames["t"] > frames["t"][0] + 1.75)[0])
    bound = split // 3
    gate = threading.Event()
    warm = KernelWarmUp(work=gate.wait).start()
    sink = Recorder()
    runner = LiveRunner(
        ListSource(frames[:split], chunk=32), Config(), [sink], warm_up=warm, hold_max_frames=bound
    )
    runner.start()
    status = lambda: runner.snapshot(last=0).warmup  # noqa: E731
    try:
        until(lambda: (w := status()) is not None and w.held_frames + w.dropped_frames == split)
        w = status()
        assert w is not None and w.dropped_frames > 0 and w.held_frames <= bound
        assert runner.frames_dropped == w.dropped_frames
        assert len(runner.snapshot().results) > 300  # the preview went on past the bound
        assert sink.steps == []
        gate.set()
        until(lambda: runner.snapshot(last=1).warmup is None)
    finally:
        gate.set()
        runner.stop()
    assert sum(len(s.frames) for s in sink.steps) == w.held_frames  # what was kept, all of it
    ev = sink.events()
    dropped = ev[ev["kind"] == EventKind.DROPPED]
    assert len(dropped) == 1 and int(dropped["value"][0]) == split - w.held_frames
    assert runner.frames_dropped == split - w.held_frames


def test_the_recording_panel_shows_the_hold_and_its_drops() -> None:
    status = RecordingStatus(path="logs/run.mcap", frames=0, bytes=1000, duration_s=3.0)
    out = io.StringIO()
    table = recording_table(status, None, None, 60, WarmUpStatus(12.0, 4242, 17))
    Console(file=out, width=60).print(table)
    text = out.getvalue()
    assert "4242 frames held for the estimator  drop 17" in text


def test_the_screen_says_the_estimator_is_being_prepared() -> None:
    snap = settled_snapshot(make_frames(300), estimator=False)
    snap.warmup = WarmUpStatus(elapsed_s=12.3, held_frames=4242)
    snap.recording = None
    app = BenchApp(Session(runner=None, fixed=snap), poll_hz=0)

    async def run() -> str:
        async with app.run_test(size=(100, 30)) as pilot:
            app.apply_snapshot(snap)
            await pilot.pause()
            return screen_text(app)

    import asyncio

    text = asyncio.run(run())
    assert "preparing the estimator · 12 s" in text
    assert "numba compiles its kernel" in text
    assert "estimator 12 s" in text.splitlines()[0]  # the status bar
    assert "g12     20.000" in text or "g12     19.9" in text  # the reference method, live
