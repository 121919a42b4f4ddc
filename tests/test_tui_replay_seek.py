"""Replay keys beyond play/step: run to the next INVALID (not only the next vote failure),
back 10 s and restart (a new session on the same log), the events' clock label. The log
is built so that each kind of stop has its own known sample number."""

from __future__ import annotations

import asyncio

import numpy as np

from bench.config import Config
from bench.live.runner import LiveRunner
from bench.live.session import Session
from bench.live.setup import LiveSetup
from bench.replay.player import ReplaySource
from bench.replay.run import replay
from bench.tui.panels.events import EventsPanel
from bench.tui.panels.pairs import PairsPanel
from bench.tui.replay_app import ReplayApp, create_app
from tests.test_tui_app import SIZE, wait_for
from tests.test_tui_support import ListFile, make_frames, screen_text

RATE = 200


def staged_log() -> np.ndarray:
    """0-299 clean; 300-349 ch3 off by 0.15 mm/s^2 (v1 fails, 2/3 votes: a vote failure,
    not INVALID); 350-399 clean; 400-449 ch2 off by 1 mm/s^2 (all votes fail: INVALID);
    450-549 clean."""
    return np.concatenate(
        [
            make_frames(300),
            make_frames(50, perturb_mps2=(0.0, 0.0, 0.00015), start=300),
            make_frames(50, start=350),
            make_frames(50, perturb_mps2=(0.0, 0.001, 0.0), start=400),
            make_frames(100, start=450),
        ]
    )


def new_session(frames: np.ndarray, paused: bool = True) -> Session:
    source = ReplaySource(ListFile(frames), paused=paused, step_s=1.0 / RATE)
    setup = LiveSetup(source, "replay staged.log", "replay-staged")
    return Session.create(
        setup, lambda sinks: LiveRunner(source, Config(), sinks, description="replay"), None
    )


def test_seek_targets_back_and_restart() -> None:
    frames = staged_log()
    res = replay(ListFile(frames), Config()).results  # the same log, fused on its own
    t_of = dict(zip(res["n"].tolist(), res["t"].tolist(), strict=True))
    back_to = int(res["n"][np.flatnonzero(res["t"] >= t_of[400] - 1.0)[0]])
    assert 195 <= back_to <= 205  # about 200 samples at 200 Hz
    made: list[Session] = []

    def restart(paused: bool) -> Session:
        made.append(new_session(frames, paused))
        return made[-1]

    session = new_session(frames)
    app = create_app(session, poll_hz=8, restart=restart)
    assert isinstance(app, ReplayApp)

    async def run() -> None:
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            await pilot.pause()
            assert "Events (log time, UTC)" in screen_text(app)
            await pilot.press("j")  # the first vote failure: the degraded stretch
            await wait_for(pilot, lambda: app.cursor_n == 300)
            await wait_for(pilot, lambda: app.query_one(PairsPanel).values["state"] == "degraded")
            await pilot.press("t")  # target: INVALID
            assert app.seek_label == "INVALID"
            await pilot.press("j")  # skips the degraded samples, stops where all votes fail
            await wait_for(pilot, lambda: app.cursor_n == 400, timeout=10)
            await wait_for(pilot, lambda: app.query_one(PairsPanel).values["state"] == "invalid")
            assert "sample 400 (at cursor)" in screen_text(app)
            app.back_s = 1.0  # 1 s of log time before sample 400
            await pilot.press("b")
            await wait_for(pilot, lambda: app.restarts == 1 and app.cursor_n is not None, 10)
            assert app.session is made[0]
            assert app.cursor_n == back_to
            await wait_for(pilot, lambda: app.query_one(PairsPanel).values["state"] == "valid")
            assert session.stopped  # the first session was stopped, not leaked
            await pilot.press("0")  # again from the first frame: panels start empty
            await wait_for(pilot, lambda: app.restarts == 2)
            assert app.session is made[1] and made[0].stopped
            assert app.query_one(EventsPanel).received == 0 or app.cursor_n is None
            await pilot.press("q")
            await wait_for(pilot, lambda: not app.is_running)

    asyncio.run(run())
    for s in (session, *made):
        s.stop()


def test_run_to_the_next_recorded_mark() -> None:
    """Marks are in the log's event record, not in what fusion reports: j with the target
    'mark' runs to the first recorded mark after the sample shown, and says when none is."""
    frames = staged_log()
    res = replay(ListFile(frames), Config()).results
    t_of = dict(zip(res["n"].tolist(), res["t"].tolist(), strict=True))
    marks = [(t_of[120], "operator mark 1"), (t_of[480], "operator mark 2")]
    session = new_session(frames)
    app = create_app(session, poll_hz=8, recorded_marks=marks)

    async def run() -> None:
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            for _ in range(4):  # vote failure -> INVALID -> exclusion -> fault -> mark
                await pilot.press("t")
            assert app.seek_label == "mark"
            await pilot.press("j")
            await wait_for(pilot, lambda: app.cursor_n == 120, timeout=10)
            await pilot.press("j")
            await wait_for(pilot, lambda: app.cursor_n == 480, timeout=10)
            await pilot.press("j")  # none left: the cursor stays, the replay stays paused
            await pilot.pause(0.3)
            assert app.cursor_n == 480 and session.replay is not None and session.replay.paused
            await pilot.press("q")
            await wait_for(pilot, lambda: not app.is_running)

    asyncio.run(run())
    session.stop()
