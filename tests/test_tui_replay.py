"""Replay in the TUI: ReplaySource pacing, flow control, pause/step, run-to-next-failure, and
the replay keys driving it. Expectations come from the frames themselves (their receive
times, the instant the fault starts) and from a plain bench.replay.run of the same log."""

from __future__ import annotations

import asyncio
import time

import numpy as np

from bench.config import Config
from bench.live.runner import LiveRunner
from bench.live.session import Session, wait_until
from bench.live.setup import LiveSetup
from bench.replay.player import ReplaySource, ReplayTap
from bench.replay.run import replay
from bench.tui.panels.pairs import PairsPanel
from bench.tui.replay_app import ReplayApp
from tests.test_tui_app import SIZE, wait_for
from tests.test_tui_support import ListFile, make_frames, screen_text

RATE = 200


def faulty_log() -> np.ndarray:
    """300 clean instants, 50 with ch2 off by 1 mm/s^2 (all three votes fail), 100 clean."""
    return np.concatenate(
        [
            make_frames(300),
            make_frames(50, perturb_mps2=(0.0, 0.001, 0.0), start=300),
            make_frames(100, start=350),
        ]
    )


def runner_for(source: ReplaySource, **kwargs: object) -> LiveRunner:
    return LiveRunner(source, Config(), [ReplayTap(source)], **kwargs)  # type: ignore[arg-type]


def test_max_speed_replays_every_frame_once_even_into_a_tiny_queue() -> None:
    frames = make_frames(3000)
    source = ReplaySource(ListFile(frames), speed=None, max_ahead=500, max_ahead_batches=4)
    runner = runner_for(source, queue_batches=8).start()
    assert wait_until(lambda: source.finished and source.consumed >= len(frames), 20)
    runner.stop()
    assert runner.frames_dropped == 0
    assert runner.frames_received == runner.pipeline.seq == len(frames)
    got = runner.snapshot().results
    want = replay(ListFile(frames), Config()).results
    assert np.array_equal(got["n"], want["n"][-len(got) :])
    assert np.array_equal(got["slopes"], want["slopes"][-len(got) :])


def test_paced_replay_follows_the_log_clock() -> None:
    """At 10x, at every instant of the source's clock (a stepped fake: no wall time) the
    frames handed out are exactly those whose log time is due: t0 + 10 * elapsed."""
    frames = make_frames(400)  # 2 s of log
    now = [100.0]
    source = ReplaySource(ListFile(frames), speed=10.0, clock=lambda: now[0])
    t0 = float(frames["t"][0])
    got: list[np.ndarray] = []
    for step in range(25):  # 0.25 s of clock: 2.5 s of log, past its end
        now[0] = 100.0 + step * 0.01
        while len(batch := source.read(0.0).frames):
            got.append(batch)
        due = t0 + (now[0] - 100.0) * 10.0  # the pacing rule, as the player computes it
        assert source.emitted == int(np.count_nonzero(frames["t"] <= due)), step
    assert np.concatenate(got).tobytes() == frames.tobytes()  # each frame once, in order
    source.close()


def test_paused_replay_holds_frames_and_steps_one_period() -> None:
    frames = make_frames(100)
    source = ReplaySource(ListFile(frames), paused=True, step_s=1.0 / RATE)
    assert not source.read(0.05)
    source.step()
    batch = source.read(0.05)
    t0 = float(frames["t"][0])
    assert len(batch.frames) > 0
    assert (batch.frames["t"] <= t0 + 1.0 / RATE).all()
    assert not source.read(0.02)  # nothing more until the next step
    source.step()
    nxt = source.read(0.05)
    assert len(nxt.frames) > 0 and (nxt.frames["t"] > batch.frames["t"][-1]).all()
    assert (nxt.frames["t"] <= t0 + 2.0 / RATE).all()
    source.close()


def test_seek_stops_at_the_first_vote_failure() -> None:
    frames = faulty_log()
    source = ReplaySource(ListFile(frames), paused=True)
    runner = runner_for(source).start()
    source.seek_failure()
    assert wait_until(lambda: source.failure is not None, 10)
    assert source.paused and not source.seeking
    assert source.failure.n == 300
    assert "failed v1,v2,v3" in source.failure.text
    time.sleep(0.2)
    n_done = int(runner.snapshot().results["n"][-1])
    assert 300 <= n_done < 300 + 2 * source.seek_chunk  # stopped right after it
    runner.stop()


def test_replay_keys_in_the_app() -> None:
    frames = faulty_log()
    source = ReplaySource(ListFile(frames), paused=True, step_s=1.0 / RATE)
    setup = LiveSetup(source, "replay test.log", "replay-test")
    session = Session.create(
        setup, lambda sinks: LiveRunner(source, Config(), sinks, description="replay test"), None
    )

    async def run() -> None:
        app = ReplayApp(session, poll_hz=8)
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            # the footer is drawn after the first refresh, which a loaded machine delays
            await wait_for(pilot, lambda: "spc Play" in screen_text(app).splitlines()[-1])
            footer = screen_text(app).splitlines()[-1]
            for key in ("spc Play", "s Speed", "n Step", "j Next", "t Target", "b Back"):
                assert key in footer
            await pilot.press("j")
            await wait_for(pilot, lambda: app.cursor_n == 300)
            await wait_for(pilot, lambda: "sample 300 (at cursor)" in screen_text(app))
            vals = app.query_one(PairsPanel).values
            assert (vals["v1"], vals["v2"], vals["v3"]) == ("FAIL", "FAIL", "FAIL")
            assert vals["final"] == "--.--" and vals["state"] == "invalid"
            assert "paused" in screen_text(app).splitlines()[0]
            await pilot.press("n")
            assert app.cursor_n == 301
            await pilot.press("s")
            assert source.speed == 10.0
            await pilot.press("s")
            assert source.speed is None
            await pilot.press("space")
            assert not source.paused and app.cursor_n is None
            await wait_for(pilot, lambda: source.finished)
            await wait_for(pilot, lambda: "end of log" in screen_text(app))
            await pilot.press("q")
            await wait_for(pilot, lambda: not app.is_running)

    asyncio.run(run())
    assert session.runner.frames_dropped == 0
    assert session.runner.pipeline.seq == len(frames)
