"""Receive-time and board-time glitches (issue 16 item 3), on hand-made frame sequences.

The samples rest on the board's ticks and counter: a lone frame with a wild receive time or
a wild board time is an outlier (counted, an event), a host clock step is a notice, and
neither invents lost samples or splits a sample. Expected values are the instants the
frames were built from.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.records.events import EventKind
from protocol.records import RawFrame
from tests.helpers import adc, assemble, instant, kinds, status_frame

T0 = 1.7e9
K = 60  # instants per stream
BAD = 30  # the instant the glitch hits


def stream(rate_known: bool) -> list[RawFrame]:
    frames = [status_frame(200, T0)] if rate_known else []
    return frames + [f for k in range(K) for f in instant(k, t0=T0)]


def position(frames: list[RawFrame], k: int, ch: int) -> int:
    """Index of instant k's channel-ch frame in ``frames``."""
    want = instant(k, t0=T0)[ch - 1]
    return next(i for i, f in enumerate(frames) if f == want)


def with_timestamp(f: RawFrame, ts: int) -> RawFrame:
    d = f.data
    return adc(f.can_id - 0x100, d[0], d[1] | d[2] << 8 | d[3] << 16, ts, f.t, d[4])


CUTS = [None, 1, 3, 100]


@pytest.mark.parametrize("rate_known", [True, False])
@pytest.mark.parametrize("cut", CUTS)
def test_one_frame_stamped_early_is_a_time_outlier_not_1310_lost_samples(rate_known, cut):
    frames = stream(rate_known)
    i = position(frames, BAD, 2)
    frames[i] = RawFrame(frames[i].t - 7.5, frames[i].can_id, frames[i].data)
    samples, events = assemble(frames, cut=cut)
    assert samples["n"].tolist() == list(range(K))  # no sample split, none invented
    assert samples["present"].all()
    assert len(kinds(events, EventKind.SAMPLES_LOST)) == 0
    out = kinds(events, EventKind.TIME_OUTLIER)
    assert out["channel"].tolist() == [2] and out["n"].tolist() == [BAD]
    assert out["value"].tolist() == [-7500]
    assert len(kinds(events, EventKind.CLOCK_STEP)) == 0
    # the sample keeps a receive time on the stream's axis (board time predicts it)
    assert abs(samples["t"][BAD] - (T0 + BAD / 200)) < 1e-3


@pytest.mark.parametrize("step_s", [5.0, 3000.0, -5.0])
@pytest.mark.parametrize("rate_known", [True, False])
@pytest.mark.parametrize("cut", CUTS)
def test_host_clock_step_is_a_notice_not_phantom_lost_samples(step_s, rate_known, cut):
    frames = stream(rate_known)
    i = position(frames, BAD, 1)
    frames = frames[:i] + [RawFrame(f.t + step_s, f.can_id, f.data) for f in frames[i:]]
    samples, events = assemble(frames, cut=cut)
    assert samples["n"].tolist() == list(range(K))
    assert samples["present"].all()
    assert len(kinds(events, EventKind.SAMPLES_LOST)) == 0
    assert len(kinds(events, EventKind.LATE)) == 0
    steps = kinds(events, EventKind.CLOCK_STEP)
    assert steps["value"].tolist() == [round(step_s * 1000)]
    assert len(kinds(events, EventKind.TIME_OUTLIER)) + len(kinds(events, EventKind.OUTLIER)) == 0


@pytest.mark.parametrize("jump_ticks", [30000, -30000, 5000])
@pytest.mark.parametrize("rate_known", [True, False])
@pytest.mark.parametrize("cut", CUTS)
def test_one_frame_with_a_wild_board_time_is_an_outlier(jump_ticks, rate_known, cut):
    """A CRC-valid frame whose timestamp jumps (+3 s, -3 s, +0.5 s) and whose counter is
    right: it alone is dropped (OUTLIER); no later frame is 'late', no sample lost."""
    frames = stream(rate_known)
    i = position(frames, BAD, 2)
    frames[i] = with_timestamp(frames[i], (BAD * 50 + jump_ticks) % 65536)
    samples, events = assemble(frames, cut=cut)
    assert samples["n"].tolist() == list(range(K))
    present = np.ones((K, 3), dtype=bool)
    if not (jump_ticks == 5000 and not rate_known):  # before the rate, the counter places it
        present[BAD, 1] = False
        out = kinds(events, EventKind.OUTLIER)
        assert out["channel"].tolist() == [2]
        assert len(kinds(events, EventKind.CLOCK_STEP)) == 0
    assert samples["present"].tolist() == present.tolist()
    assert len(kinds(events, EventKind.LATE)) == 0
    assert len(kinds(events, EventKind.SAMPLES_LOST)) == 0


@pytest.mark.parametrize("cut", CUTS)
def test_board_clock_that_really_jumps_is_followed_after_one_frame(cut):
    """Board time +3 s from instant BAD on (the counter runs on): the first frame is taken
    for an outlier, the second shows the jump is real and the stream follows it."""
    frames = stream(True)
    i = position(frames, BAD, 1)
    frames = frames[:i] + [
        with_timestamp(f, (f.data[5] | f.data[6] << 8) + 30000) for f in frames[i:]
    ]
    samples, events = assemble(frames, cut=cut)
    assert len(kinds(events, EventKind.OUTLIER)) == 1
    assert kinds(events, EventKind.CLOCK_STEP)["value"].tolist() == [-3000]
    assert len(samples) == K
    assert samples["present"][BAD + 1 :].all()  # every later sample whole
    assert samples["present"][BAD].tolist() == [False, True, True]
    assert np.all(np.diff(samples["ticks"][BAD + 1 :]) == 50)
