"""Small pieces of the live path: the latency ring, the stats copy, record joining and the
plot pacer -- each against an independent expectation."""

from __future__ import annotations

import copy
from collections import deque

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.live.runner import LatencyRing
from bench.pipeline.stats import Stats
from bench.records.arrays import concat_records
from bench.tui.panels.plot import PlotPacer
from protocol.frames import FRAME_DTYPE
from tests.helpers import until

values = st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=0, max_size=40)


@settings(max_examples=200, deadline=None)
@given(st.lists(values, max_size=30), st.integers(1, 25))
def test_latency_ring_keeps_the_last_finite_values(chunks: list[list[float]], size: int) -> None:
    ring = LatencyRing(size)
    kept: deque[float] = deque(maxlen=size)  # the reference: a deque of the finite values
    for chunk in chunks:
        ring.extend(np.array(chunk, dtype=np.float64))
        kept.extend(v for v in chunk if np.isfinite(v))
        assert sorted(ring.values().tolist()) == sorted(kept)


def test_latency_ring_values_are_a_copy() -> None:
    ring = LatencyRing(3)
    ring.extend(np.array([1.0, 2.0]))
    v = ring.values()
    v[:] = 0
    assert sorted(ring.values().tolist()) == [1.0, 2.0]


def test_stats_copy_is_deep_and_equal() -> None:
    s = Stats()
    s.frames = 7
    s.frames_by_id.update({0x101: 3, 0x102: 4})
    s.channels[1].frames = 5
    s.channels[2].first_t = 1.5
    s.vote_failures[0] = 2
    s.events.update({3: 1})
    c = s.copy()
    assert c == s == copy.deepcopy(s)
    c.frames_by_id[0x101] += 1
    c.channels[1].frames += 1
    c.vote_failures[0] += 1
    c.events[3] += 1
    assert s.frames_by_id[0x101] == 3 and s.channels[1].frames == 5
    assert s.vote_failures[0] == 2 and s.events[3] == 1


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(0, 6), min_size=1, max_size=12))
def test_concat_records_equals_numpy_concatenate(sizes: list[int]) -> None:
    rng = np.random.default_rng(sum(sizes))
    parts = []
    for n in sizes:
        a = np.zeros(n, dtype=FRAME_DTYPE)
        a["t"] = rng.normal(size=n)
        a["id"] = rng.integers(0, 2**11, size=n)
        a["data"] = rng.integers(0, 256, size=(n, 8))
        parts.append(a)
    got = concat_records(parts)
    want = np.concatenate(parts)
    assert got.dtype == FRAME_DTYPE and got.tobytes() == want.tobytes()


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_plot_pacer_keeps_drawing_under_its_cpu_share() -> None:
    clock = _Clock()
    pacer = PlotPacer(share=0.15, clock=clock)
    assert pacer.due()  # the first drawing is always due
    pacer.drew(100.0, 0.15)  # took 150 ms: the next one no sooner than 1 s after its start
    clock.now = 100.5
    assert not pacer.due()
    clock.now = 100.99
    assert not pacer.due()
    clock.now = 101.0
    assert pacer.due()
    pacer.drew(101.0, 0.015)  # a cheap drawing (small terminal): 10 Hz allowed
    clock.now = 101.1
    assert pacer.due()
    pacer.drew(101.1, 0.3)
    clock.now = 101.2
    assert not pacer.due()
    pacer.force()  # a new window or size: drawn at once
    assert pacer.due()
    assert pacer.drawn == 3 and pacer.skipped == 3


def test_the_emulated_board_waits_for_the_bench(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """open_emulator's board plays only once start_board() is called (after the runner
    starts), so no frame queues up in the bus while the run and its log are set up."""
    import time

    from bench.live.setup import open_emulator

    sc = tmp_path / "short.toml"
    sc.write_text("duration_s = 5.0\nsample_rate_hz = 200\nseed = 3\n", encoding="utf-8")
    setup = open_emulator(sc)
    try:
        time.sleep(0.3)
        assert setup.emulator.frames_sent == 0 and not setup.source.read(0.05)
        setup.start_board()
        setup.start_board()  # idempotent
        until(lambda: setup.emulator.frames_sent >= 30, "30 frames sent")
        assert len(setup.source.read(1.0).frames) > 0
    finally:
        setup.close()
