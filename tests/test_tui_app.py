"""The TUI driven headless (App.run_test + Pilot) on a real LiveRunner fed with known frames.

Expectations are independent of the UI: the values on screen must equal what the pipeline
computes for the same frames when replayed on its own, and (to the last quantisation step)
the gradient the frames were built from.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from bench.config import Config
from bench.live.runner import LiveRunner
from bench.live.session import Session
from bench.live.setup import LiveSetup
from bench.replay.run import replay
from bench.tui.app import BenchApp, next_tolerance
from bench.tui.panels.events import EventsPanel, MarksPanel
from bench.tui.panels.pairs import PairsPanel
from tests.test_tui_support import (
    FakeSink,
    ListFile,
    ListSource,
    codes_for,
    make_frames,
    screen_text,
)

SIZE = (100, 30)


def make_session(
    frames: np.ndarray, *, open_sink: Callable[[], object] | None = None, first: object = None
) -> tuple[Session, ListSource]:
    source = ListSource(frames)
    setup = LiveSetup(source, "test frames", "test")
    session = Session.create(
        setup,
        lambda sinks: LiveRunner(source, Config(), sinks, description="test frames"),
        open_sink,
        first,
    )
    return session, source


async def wait_for(pilot: object, pred: Callable[[], bool], timeout: float = 20.0) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise AssertionError("condition not reached in time")
        await asyncio.sleep(0.02)


async def settle(pilot: object, app: BenchApp, session: Session, frames_total: int) -> None:
    """Wait until the runner has processed every frame and a later snapshot is on screen."""
    runner = session.runner
    assert runner is not None
    await wait_for(pilot, lambda: runner.pipeline.seq >= frames_total)

    def delivered() -> bool:  # the pipeline counts a step's results before it delivers them
        snap = runner.snapshot()
        return snap.stats.samples == len(snap.results)

    await wait_for(pilot, delivered)
    seen = app.snapshots_received
    await wait_for(pilot, lambda: app.snapshots_received >= seen + 2)


def test_values_on_screen_match_the_fusion_output() -> None:
    frames = make_frames(600, gradient_permil=20.0)
    expected = replay(ListFile(frames), Config()).results
    last = expected[-1]
    session, _ = make_session(frames)

    async def run() -> None:
        app = BenchApp(session, poll_hz=8)
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app, session, len(frames))
            pairs = app.query_one(PairsPanel).values
            text = screen_text(app)
            for k, name in enumerate(("g12", "g23", "g13")):
                shown = f"{float(last['slopes'][k]):.3f}"
                assert pairs[name] == shown
                assert shown in text
                # and the pipeline itself is right: the frames were built for 20 permil
                assert abs(float(last["slopes"][k]) - 20.0) < 0.05
            assert pairs["final"] == f"{float(last['gradient']):.2f}"
            assert [pairs[v] for v in ("v1", "v2", "v3")] == ["PASS"] * 3
            assert pairs["state"] == "valid"
            assert f"sample {int(last['n'])}" in text
            for code in codes_for(20.0):
                assert f"{code:+d}" in text
            assert "200.0" in text  # frame rate from receive times
            assert "RUN 200 Hz 31 °C 24.1 V" in text
            assert f"{len(frames)} recv" in text
            await pilot.press("q")
            await wait_for(pilot, lambda: not app.is_running)
        assert session.stopped

    asyncio.run(run())


def test_pause_display_freezes_screen_not_acquisition_or_logging() -> None:
    first = make_frames(200, gradient_permil=20.0)
    sink = FakeSink()
    session, source = make_session(first, first=sink)

    async def run() -> None:
        app = BenchApp(session, poll_hz=8)
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app, session, len(first))
            before = dict(app.query_one(PairsPanel).values)
            await pilot.press("p")
            assert app.display_paused
            assert " PAUSED " in screen_text(app).splitlines()[0]  # the title says so
            assert app.title.endswith("PAUSED")
            more = make_frames(200, gradient_permil=35.0, start=200)
            source.feed(more)
            total = len(first) + len(more)
            await settle(pilot, app, session, total)
            assert app.query_one(PairsPanel).values == before  # screen frozen
            assert sink.frames == total  # ...while logging went on
            await pilot.press("p")
            await wait_for(pilot, lambda: app.query_one(PairsPanel).values != before)
            assert abs(float(app.query_one(PairsPanel).values["g23"]) - 35.0) < 0.05

    asyncio.run(run())
    session.stop()  # leaving run_test is not quitting; the command stops the session then
    assert sink.closed


def test_record_key_stops_and_starts_files_without_losing_frames() -> None:
    frames = make_frames(100)
    first = FakeSink("logs/first.mcap")
    opened: list[FakeSink] = []

    def open_sink() -> FakeSink:
        opened.append(FakeSink(f"logs/next-{len(opened)}.mcap"))
        return opened[-1]

    session, source = make_session(frames, open_sink=open_sink, first=first)

    async def run() -> None:
        app = BenchApp(session, poll_hz=8)
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app, session, len(frames))
            assert "● REC" in screen_text(app)
            await pilot.press("r")
            await wait_for(pilot, lambda: first.closed)
            assert not session.recorder.active
            await pilot.pause(0.2)
            assert "not recording" in screen_text(app)
            await pilot.press("r")
            assert session.recorder.active and len(opened) == 1
            source.feed(make_frames(100, start=100))
            await settle(pilot, app, session, len(source.frames))
            assert "logs/next-0.mcap" in screen_text(app)
            await pilot.press("q")
            await wait_for(pilot, lambda: not app.is_running)
        assert first.frames == len(frames)
        assert first.writes_after_close == 0
        assert opened[0].closed  # quitting closed the second file too
        assert opened[0].frames > 0 and first.frames + opened[0].frames <= len(source.frames)

    asyncio.run(run())


def test_mark_goes_to_the_log_and_the_event_list() -> None:
    sink = FakeSink()
    session, _ = make_session(make_frames(50), first=sink)

    async def run() -> None:
        app = BenchApp(session, poll_hz=8)
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app, session, len(session.setup.source.frames))
            await pilot.press("m")
            await pilot.press("m")
            assert sink.marks == ["operator mark 1", "operator mark 2"]
            marks = app.query_one(MarksPanel)
            await wait_for(pilot, lambda: any("operator mark 2" in m for m in marks.texts()))
            await wait_for(pilot, lambda: "operator mark 2" in screen_text(app))
            # marks have a list of their own: none of them in the events list
            assert not any("mark" in e for e in app.query_one(EventsPanel).texts())

    asyncio.run(run())
    session.stop()


def test_tolerance_keys_change_the_vote_live() -> None:
    # ch3 off by 0.15 mm/s^2: slopes about 20.0 / 21.5 / 20.8, so v1 fails at 1 permil
    frames = make_frames(100, perturb_mps2=(0.0, 0.0, 0.00015))
    session, source = make_session(frames)

    async def run() -> None:
        app = BenchApp(session, poll_hz=8)
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app, session, len(frames))
            vals = app.query_one(PairsPanel).values
            assert (vals["v1"], vals["v2"], vals["v3"]) == ("FAIL", "PASS", "PASS")
            assert vals["state"] == "degraded"
            await pilot.press("plus")
            assert session.runner.pipeline.tolerance_permil == 2.0
            source.feed(make_frames(100, perturb_mps2=(0.0, 0.0, 0.0002), start=100))
            await settle(pilot, app, session, len(source.frames))
            vals = app.query_one(PairsPanel).values
            assert (vals["v1"], vals["v2"], vals["v3"]) == ("PASS", "PASS", "PASS")
            assert "tol ±2 ‰" in screen_text(app)
            await pilot.press("minus", "minus")
            assert session.runner.pipeline.tolerance_permil == 0.5
            await wait_for(pilot, lambda: "tolerance set to 0.5" in screen_text(app))
            assert any(
                "tolerance set to 0.5 permil" in m for m in app.query_one(MarksPanel).texts()
            )

    asyncio.run(run())
    session.stop()


def test_tolerance_ladder() -> None:
    assert next_tolerance(1.0, 1) == 2.0
    assert next_tolerance(1.0, -1) == 0.5
    assert next_tolerance(1.5, 1) == 2.0
    assert next_tolerance(1.5, -1) == 1.0
    assert next_tolerance(0.1, -1) == 0.1
    assert next_tolerance(100.0, 1) == 100.0


def test_quit_finalises_the_mcap_file(tmp_path: Path) -> None:
    mcap_writer = pytest.importorskip("bench.mcaplog.sink")
    from mcap.reader import make_reader

    frames = make_frames(400)
    path = tmp_path / "run.mcap"
    sink = mcap_writer.McapSink(path, Config(), {"test": "tui"})
    session, _ = make_session(frames, first=sink)

    async def run() -> None:
        app = BenchApp(session, poll_hz=10)
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            await wait_for(pilot, lambda: session.runner.pipeline.seq >= len(frames))
            await pilot.press("m")
            await pilot.press("q")
            await wait_for(pilot, lambda: not app.is_running, timeout=10)
        assert app.return_code == 0

    asyncio.run(run())
    assert session.runner.finished.is_set()
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics is not None  # finished file: summary
    assert sink.frames_logged == len(frames)


def test_keys_are_in_the_footer_and_the_command_palette() -> None:
    session, _ = make_session(make_frames(10))

    async def run() -> None:
        app = BenchApp(session, poll_hz=0)
        async with app.run_test(size=SIZE) as pilot:
            # the footer is drawn after the first refresh, which a loaded machine delays
            await wait_for(pilot, lambda: "Quit" in screen_text(app).splitlines()[-1])
            footer = screen_text(app).splitlines()[-1]
            for key in ("q Quit", "p Pause display", "r Rec", "m Mark", "+ Tol+", "- Tol-"):
                assert key in footer
            assert "Play/pause" not in footer  # replay keys only in replay mode
            titles = {c.title for c in app.get_system_commands(app.screen)}
            assert {
                "Pause display",
                "Record on/off",
                "Mark event",
                "Tolerance up",
                "Tolerance down",
                "Quit",
            } <= titles
            await pilot.press("ctrl+p")
            await pilot.press(*"mark")
            await pilot.pause(0.3)
            assert "Mark event" in screen_text(app)

    asyncio.run(run())
    session.stop()


def test_a_sigterm_before_the_screen_is_up_quits_once_it_is(tmp_path: Path) -> None:
    """The run and its log start before the screen; a SIGTERM in between was lost where the
    process inherited it as ignored (`nohup`, .ci/run under nohup hung 120 s on SIGHUP) or
    ended the process at once. It is kept, and the screen quits like `q` when it comes up."""
    import os
    import signal

    mcap_writer = pytest.importorskip("bench.mcaplog.sink")
    frames = make_frames(200)
    sink = mcap_writer.McapSink(tmp_path / "run.mcap", Config(), {"test": "tui"})
    session, _ = make_session(frames, first=sink)
    app = BenchApp(session, poll_hz=10, handle_signals=True)
    held = app.hold_signals()
    try:
        session.start()
        os.kill(os.getpid(), signal.SIGTERM)  # before the screen: kept, not acted on
        assert app.early_signals == [signal.SIGTERM]

        async def run() -> None:
            async with app.run_test(size=SIZE) as pilot:
                await wait_for(pilot, lambda: not app.is_running, timeout=30)

        asyncio.run(run())
    finally:
        for sig, handler in held.items():
            signal.signal(sig, handler)
        session.stop()
    assert app.return_code == 0 and app.quitting
    assert session.runner.finished.is_set()
    assert sink.frames_logged == len(frames)
