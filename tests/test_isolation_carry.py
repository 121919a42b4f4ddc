"""A residual alarm that turns ambiguous (a curve's v^2/R, the reference acceleration
lagging) still names the channel it named before: a drifting channel is not readmitted
for a moment of doubt (bench/fusion/isolation.py carry_named and its scalar twin)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from bench.fusion.isolation import AMBIGUOUS, carry_named, carry_named_one

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
    st.integers(0, 60),
)
def test_vector_and_scalar_twins_agree_however_the_stream_is_cut(rows, carry0, cut) -> None:
    single = np.array([r[0] for r in rows], dtype=np.int8)
    cand = np.array([r[1] or r[0] >= 0 or r[0] == A for r in rows], dtype=bool)
    cut = min(cut, len(rows))
    a, c = carry_named(single[:cut], cand[:cut], carry0)
    b, c = carry_named(single[cut:], cand[cut:], c)
    vector = [*a.tolist(), *b.tolist()]
    scalar, c1 = [], carry0
    for s_, k in zip(single.tolist(), cand.tolist(), strict=True):
        out, c1 = carry_named_one(s_, k, c1)
        scalar.append(out)
    assert vector == scalar and c == c1
