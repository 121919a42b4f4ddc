"""A residual alarm that turns ambiguous (a curve's v^2/R, the reference acceleration
lagging) still names the channel it named before: a drifting channel is not readmitted
for a moment of doubt (bench/fusion/isolation.py carry_named)."""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from bench.fusion.isolation import AMBIGUOUS, carry_named

A = AMBIGUOUS


def test_an_ambiguous_alarm_keeps_the_channel_named_and_a_quiet_sample_ends_it() -> None:
    single = np.array([-1, 0, A, A, -1, A, -1, 2, A, -1, A])
    cand = np.array([True, True, True, True, False, True, True, True, True, True, True])
    named, carry = carry_named(single, cand, -1)
    # ch1 (0) named; ambiguous keeps it; a sample without three healthy channels tells
    # nothing (still ch1 after it); a quiet sample with all three ends the alarm
    assert named.tolist() == [-1, 0, 0, 0, -1, 0, -1, 2, 2, -1, -1]
    assert carry == -1


def test_the_carry_crosses_batches() -> None:
    named, carry = carry_named(np.array([1, A]), np.array([True, True]), -1)
    assert named.tolist() == [1, 1] and carry == 1
    named, carry = carry_named(np.array([A, A]), np.array([True, True]), carry)
    assert named.tolist() == [1, 1] and carry == 1


@given(
    st.lists(st.tuples(st.sampled_from([A, -1, 0, 1, 2]), st.booleans()), max_size=60),
    st.sampled_from([-1, 0, 1, 2]),
    st.lists(st.integers(0, 60), max_size=8),
)
def test_the_same_names_however_the_stream_is_cut(rows, carry0, cuts) -> None:
    """Pushes of any length, down to one sample (live), give what one push of all gives,
    and that is the rule stated in carry_named's docstring, applied sample by sample."""
    single = np.array([r[0] for r in rows], dtype=np.int8)
    cand = np.array([r[1] or r[0] >= 0 or r[0] == A for r in rows], dtype=bool)
    whole, carry_whole = carry_named(single, cand, carry0)
    pieces, c = [], carry0
    bounds = sorted({0, len(rows), *(min(x, len(rows)) for x in cuts)})
    for lo, hi in itertools.pairwise(bounds):
        out, c = carry_named(single[lo:hi], cand[lo:hi], c)
        pieces += out.tolist()
    assert pieces == whole.tolist() and c == carry_whole
    expected, alarm = [], carry0  # the channel the current alarm named, -1 for none
    for s_, k in zip(single.tolist(), cand.tolist(), strict=True):
        if s_ >= 0:
            alarm = s_  # a verdict names its channel
        elif s_ == -1 and k:
            alarm = -1  # three healthy channels and no alarm: the alarm ends
        expected.append(alarm if s_ == A else s_)
    assert whole.tolist() == expected and carry_whole == alarm
