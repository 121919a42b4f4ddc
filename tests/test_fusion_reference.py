"""The reference method (METHOD.md sections 1-3) against hand-computed values and Table 1."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.fusion.reference import fuse, pair_gradients, vote, weights

NOMINAL = np.radians([30.0, 0.0, -30.0])
G = 9.80665

# Table 1 of the method, typed in from the document: (v1, v2, v3) -> (w(s1), w(s2), w(s3))
TABLE_1 = [
    ((1, 1, 1), (1 / 3, 1 / 3, 1 / 3)),
    ((0, 1, 1), (1 / 4, 1 / 4, 1 / 2)),
    ((1, 0, 1), (1 / 2, 1 / 4, 1 / 4)),
    ((1, 1, 0), (1 / 4, 1 / 2, 1 / 4)),
    ((0, 0, 1), (1 / 2, 0, 1 / 2)),
    ((0, 1, 0), (0, 1 / 2, 1 / 2)),
    ((1, 0, 0), (1 / 2, 1 / 2, 0)),
    ((0, 0, 0), (0, 0, 0)),
]


@pytest.mark.parametrize(("votes", "expected"), TABLE_1)
def test_weights_follow_table_1_exactly(votes, expected):
    w = weights(np.array([votes], dtype=bool))
    assert w[0].tolist() == list(expected)


@pytest.mark.parametrize(("votes", "expected"), TABLE_1)
def test_final_gradient_is_the_weighted_sum_and_invalid_when_all_votes_fail(votes, expected):
    # slope values chosen so that exactly the wanted votes pass with tolerance 1:
    # build them from the vote pattern by brute force over a small grid.
    grid = [0.0, 0.6, 1.2, 3.0, 5.0]
    for s in ((a, b, c) for a in grid for b in grid for c in grid):
        v = (abs(s[0] - s[1]) <= 1, abs(s[1] - s[2]) <= 1, abs(s[0] - s[2]) <= 1)
        if v == tuple(bool(x) for x in votes):
            break
    slopes = np.array([s])
    got_votes = vote(slopes, 1.0)
    assert tuple(got_votes[0]) == tuple(bool(x) for x in votes)
    w = weights(got_votes)[0]
    expected_gradient = sum(wk * sk for wk, sk in zip(expected, s, strict=True))
    if any(votes):
        assert math.isclose(float((w * slopes[0]).sum()), expected_gradient, rel_tol=1e-15)


def _accels(alpha: float, a: float, angles=NOMINAL, g=G):
    return np.array([[a * math.cos(t) + g * math.sin(alpha + t) for t in angles]])


@pytest.mark.parametrize("permil", [0.5, 5.0, 20.0, 35.0])
def test_pair_gradients_recover_the_gradient_with_train_acceleration(permil):
    alpha = math.atan(permil / 1000)
    s = pair_gradients(_accels(alpha, a=0.7), NOMINAL, G)
    assert s[0] == pytest.approx([permil] * 3, abs=1e-6)


def test_pair_gradient_has_no_sign():
    s = pair_gradients(_accels(math.atan(-0.010), a=0.0), NOMINAL, G)
    assert s[0] == pytest.approx([10.0] * 3, abs=1e-6)


def test_cosine_beyond_one_is_clamped_to_zero_gradient():
    # a_i chosen so that cos(alpha_12) computes to slightly more than 1
    acc = _accels(0.0, 0.0) + np.array([[0.0, -1e-4, 0.0]])
    s = pair_gradients(acc, NOMINAL, G)
    assert s[0, 0] == 0.0  # pair (1, 2): clamped
    # by hand: cos = (a1 cos0 - a2 cos30) / (g sin 30)
    a1, a2 = acc[0, 0], acc[0, 1]
    assert (a1 * 1 - a2 * math.cos(math.radians(30))) / (G * math.sin(math.radians(30))) > 1


def test_missing_channel_empties_its_two_pairs_and_fails_their_votes():
    acc = _accels(math.atan(0.005), 0.0)
    acc[0, 2] = np.nan
    r = fuse(acc, NOMINAL, G, 1.0)
    assert not np.isnan(r.slopes[0, 0]) and np.isnan(r.slopes[0, 1]) and np.isnan(r.slopes[0, 2])
    assert r.votes[0].tolist() == [False, False, False]
    assert not r.valid[0] and np.isnan(r.gradient[0])


QUIET_NAN = bytes.fromhex("000000000000f87f")  # IEEE 754 float64 0x7ff8000000000000, LE


@pytest.mark.parametrize("bad", [np.nan, -np.nan])
def test_uncomputable_slopes_are_the_one_quiet_nan(bad):
    """A log writes NaN as JSON null and reads back 0x7ff8...: the sign-bit NaN that SIMD
    arccos can return would make the recorded results differ from the live ones."""
    acc = np.repeat(_accels(math.atan(0.005), 0.0), 40, axis=0)
    acc[:, 1] = bad
    for slopes in (fuse(acc, NOMINAL, G, 1.0).slopes, fuse(acc[:2], NOMINAL, G, 1.0).slopes):
        assert np.isnan(slopes[:, :2]).all()  # the pairs with ch2: g12, g23
        assert {v.tobytes() for v in slopes[:, :2].ravel()} == {QUIET_NAN}
        assert np.isfinite(slopes[:, 2]).all()  # g13 does not use ch2


def test_one_bad_sensor_corrupts_two_slopes_and_all_votes_fail():
    """METHOD.md: one faulty channel usually makes the reference method report nothing."""
    acc = _accels(math.atan(0.010), 0.5)
    acc[0, 2] += 0.01  # ch3 off by 1 cm/s^2
    r = fuse(acc, NOMINAL, G, 1.0)
    assert r.slopes[0, 0] == pytest.approx(10.0, abs=1e-6)
    assert abs(r.slopes[0, 1] - 10) > 1 and abs(r.slopes[0, 2] - 10) > 1
    assert not r.valid[0]


def test_batch_equals_row_by_row_on_a_long_randomised_stream():
    rng = np.random.default_rng(1)
    n = 20_000
    alpha = np.arctan(rng.uniform(-0.04, 0.04, n))
    a = rng.uniform(-1, 1, n)
    acc = a[:, None] * np.cos(NOMINAL) + G * np.sin(alpha[:, None] + NOMINAL)
    acc += rng.normal(0, 2e-4, acc.shape)
    acc[rng.random(acc.shape) < 0.02] = np.nan
    whole = fuse(acc, NOMINAL, G, 0.5)
    rows = [fuse(acc[i : i + 1], NOMINAL, G, 0.5) for i in range(0, n, 97)]
    idx = np.arange(0, n, 97)
    for name in ("slopes", "votes", "weights", "gradient", "valid"):
        a_whole = getattr(whole, name)[idx]
        a_rows = np.concatenate([getattr(r, name) for r in rows])
        assert a_whole.tobytes() == a_rows.tobytes(), name


def test_gradient_is_the_table_1_weighted_sum_in_every_vote_pattern():
    """Every row of noisy streams against Table 1, typed in above, applied by hand to the
    row's slope values; any cut of a stream agrees bytewise. The slope value of the pair
    around the middle angle lies between the other two, so each channel order makes some
    patterns impossible: the three orders below give all eight between them."""
    table = {tuple(bool(v) for v in votes): w for votes, w in TABLE_1}
    patterns = set()
    rng = np.random.default_rng(5)
    n = 3000
    for angles in (NOMINAL, np.radians([30.0, -30.0, 0.0]), np.radians([0.0, 30.0, -30.0])):
        alpha = np.arctan(rng.uniform(0.01, 0.1, n))
        noise = rng.normal(0, 1, (n, 3)) * rng.choice([1e-4, 1e-3, 1e-2], (n, 1))
        acc = G * np.sin(alpha[:, None] + angles) + noise
        acc[rng.random(acc.shape) < 0.05] = np.nan
        r = fuse(acc, angles, G, 5.0)
        for slopes, votes, gradient in zip(r.slopes, r.votes, r.gradient, strict=True):
            key = tuple(votes.tolist())
            patterns.add(key)
            if not any(key):
                assert math.isnan(gradient)
                continue
            w = table[key]
            expected = sum(wk * sk for wk, sk in zip(w, slopes.tolist(), strict=True) if wk)
            assert gradient == pytest.approx(expected, rel=1e-15)
        cuts = np.cumsum(rng.integers(1, 40, n))
        parts = [fuse(p, angles, G, 5.0) for p in np.split(acc, cuts[cuts < n])]
        for name in ("slopes", "votes", "weights", "gradient", "valid"):
            joined = np.concatenate([getattr(p, name) for p in parts])
            assert joined.tobytes() == np.ascontiguousarray(getattr(r, name)).tobytes(), name
    assert len(patterns) == 8
