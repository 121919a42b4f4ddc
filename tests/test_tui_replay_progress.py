"""The replay TUI's progress, seeks and clock (issue 28: ``b`` at 5:37 of a 9-min log still
seeking 7 s later, progress stuck at 8 % for ~30 s, an emulator log's times labelled UTC
reading 00:07:50). Expectations come from the frames themselves: how many there are, their
times; the pipeline's side is played by hand (what ReplayTap reports back)."""

from __future__ import annotations

import asyncio
import itertools
import math
from pathlib import Path

import numpy as np

from bench.config import Config
from bench.live.runner import LiveRunner
from bench.live.session import Session
from bench.live.setup import LiveSetup
from bench.mcaplog.sink import McapSink
from bench.mcaplog.source import McapFrameSource
from bench.pipeline.steps import Pipeline
from bench.replay.player import SEEK_AHEAD_S, Failure, ReplaySource
from bench.replay.run import run_steps
from bench.tui.replay_app import ReplayApp
from devices.base import SourceBatch
from tests.test_tui_app import SIZE, wait_for
from tests.test_tui_support import ListFile, make_frames, screen_text

RATE = 200


def consume(source: ReplaySource, until: float = math.inf) -> list[SourceBatch]:
    """Read the source as a runner would, telling it each batch was fused at once; when a
    frame at or past ``until`` goes out, report the sample there (what ReplayTap does)."""
    out: list[SourceBatch] = []
    consumed = 0
    while True:
        batch = source.read(0.02)
        if not batch:
            if source.finished or not (source.seeking or not source.paused):
                return out
            continue
        out.append(batch)
        consumed += len(batch.frames)
        source.consumed_to(consumed, len(out))
        if len(batch.frames) and float(batch.frames["t"][-1]) >= until:
            source.failure_found(Failure(float(batch.frames["t"][-1]), 0, "sample"))


def test_progress_moves_with_every_step_through_a_log_of_one_chunk(tmp_path: Path) -> None:
    """An MCAP log's read position moves by whole chunks (one here; 30 s of a demo log on
    the bench): the progress counts the frames fused against the frames the file holds."""
    frames = make_frames(2000)  # 10 s
    path = tmp_path / "run.mcap"
    sink = McapSink(path, Config(), {"source": "progress test"}, chunk_size=16 << 20)
    try:
        for step in run_steps(Pipeline(Config()), [SourceBatch(frames)]):
            sink.write(step)
    finally:
        sink.close()
    source = ReplaySource(McapFrameSource(path), speed=None, batch_frames=256)
    fractions, positions, fused = [], [], 0
    for batch in iter(lambda: source.read(0.05), None):
        if not batch and source.finished:
            break
        fused += len(batch.frames)
        source.consumed_to(fused, 0)
        status = source.status()
        fractions.append(status.fraction)
        positions.append(status.position / status.size)
        if source.finished:
            break
    source.close()
    assert fused == len(frames)
    assert len(set(positions)) <= 2  # the file's position: the one chunk, then the end
    assert len(fractions) >= len(frames) // 256  # one figure per batch, each one higher
    assert all(b > a for a, b in itertools.pairwise(fractions))
    want = np.cumsum([256] * (len(frames) // 256) + [len(frames) % 256]) / len(frames)
    assert np.allclose(fractions[: len(want)], want[: len(fractions)])
    assert fractions[-1] == 1.0


def test_progress_of_a_log_that_does_not_say_its_length_is_estimated_from_its_bytes() -> None:
    frames = make_frames(1000)
    source = ReplaySource(ListFile(frames), speed=None, batch_frames=500)  # 500 "bytes" a read
    fused = 0
    seen = []
    while not source.finished:
        batch = source.read(0.02)
        fused += len(batch.frames)
        source.consumed_to(fused, 0)
        seen.append(source.status().fraction)
    assert seen[-1] == 1.0
    assert all(b >= a for a, b in itertools.pairwise(seen))


def test_a_seek_to_a_time_hands_out_what_lies_before_it_in_full_batches() -> None:
    """``b`` restarts the replay and seeks the time 10 s back: everything up to near that
    time goes out in the log's own batches (2048 frames), not 64 at a time; past it at most
    SEEK_AHEAD_S of log, so the seek stops close after the sample it looks for."""
    frames = make_frames(20 * RATE)  # 20 s
    t0 = float(frames["t"][0])
    until = t0 + 15.0
    source = ReplaySource(ListFile(frames), paused=True, batch_frames=2048, seek_chunk=64)
    source.seek_time(until)
    batches = consume(source, until)
    assert not source.seeking and source.paused  # it stopped there
    last = max(float(b.frames["t"][-1]) for b in batches)
    assert until <= last <= until + SEEK_AHEAD_S + 1.0 / RATE
    near = until - SEEK_AHEAD_S
    before = [len(b.frames) for b in batches if float(b.frames["t"][-1]) <= near]
    assert sum(before) == int(np.count_nonzero(frames["t"] <= near))
    assert min(before[:-1]) == 2048  # full batches (the last may end at the batch's end)


def test_a_seek_to_an_event_runs_half_a_second_of_log_ahead() -> None:
    frames = make_frames(10 * RATE)
    t0 = float(frames["t"][0])
    per_s = len(frames) / float(frames["t"][-1] - t0)
    source = ReplaySource(ListFile(frames), paused=True, batch_frames=8192, seek_chunk=64)
    source.seek_event(frozenset({99}))  # a kind that never comes: it runs to the end
    sizes = [len(b.frames) for b in consume(source)]
    assert sum(sizes) == len(frames)
    steady = sizes[len(sizes) // 4 : -2]  # once it knows the log's frame rate
    assert min(steady) > 64
    assert max(steady) <= per_s * SEEK_AHEAD_S * 1.05


def replay_app(frames: np.ndarray) -> tuple[ReplayApp, Session]:
    source = ReplaySource(ListFile(frames), paused=True, step_s=1.0 / RATE)
    setup = LiveSetup(source, "replay test.log", "replay-test")
    session = Session.create(
        setup, lambda sinks: LiveRunner(source, Config(), sinks, description="replay"), None
    )
    return ReplayApp(session, poll_hz=8), session


def events_title(frames: np.ndarray) -> str:
    app, session = replay_app(frames)

    async def run() -> str:
        session.start()
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("space")
            await wait_for(pilot, lambda: "Events (log time)" not in screen_text(app))
            title = next(line for line in screen_text(app).splitlines() if "Events (" in line)
            await pilot.press("q")
            await wait_for(pilot, lambda: not app.is_running)
            return title

    try:
        return asyncio.run(run())
    finally:
        session.stop()


def test_an_emulator_logs_times_are_run_time_not_utc() -> None:
    """An emulator's log counts from 0: 470 s into it is run time 00:07:50, not UTC."""
    assert "Events (run time)" in events_title(make_frames(200, t0=0.0))


def test_a_wall_clock_logs_times_are_utc() -> None:
    assert "Events (log time, UTC)" in events_title(make_frames(200))  # 2023-11-14 on
