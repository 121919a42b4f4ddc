"""Pieces of the estimator against hand-computed values: geometry, Kalman filter, clock
alignment, stuck detection, exclusion latch, settings."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from bench.config import EstimatorSettings, config_from_dict
from bench.errors import ConfigError
from bench.fusion.isolation import ExclusionLatch, Reason, StuckDetector
from bench.fusion.kalman import ACCEL0_MPS2, SpeedKalman
from bench.fusion.least_squares import FULL, geometry, solve
from bench.fusion.speed_ref import ReferenceAcceleration, leaky_min
from bench.records.board import SPEED_DTYPE
from bench.records.events import EventKind
from bench.records.samples import SAMPLE_DTYPE

NOMINAL = tuple(math.radians(a) for a in (30.0, 0.0, -30.0))


# ------------------------------------------------------------------------- geometry


def test_pair_and_triple_solutions_match_the_hand_derived_formulas() -> None:
    geo = geometry(NOMINAL)
    a = np.array([[1.3, 0.2, -0.7]])
    c30, s30 = math.cos(math.radians(30)), 0.5
    # ch1 + ch3: a1 = u c + w s, a3 = u c - w s
    u, w = solve(np.array([[1.3, 0.0, -0.7]]), np.array([5]), geo)
    assert u[0] == pytest.approx((1.3 - 0.7) / (2 * c30), rel=1e-14)
    assert w[0] == pytest.approx((1.3 + 0.7) / (2 * s30), rel=1e-14)
    # ch1 + ch2: u = a2, w = (a1 - a2 c) / s
    u, w = solve(np.array([[1.3, 0.2, 0.0]]), np.array([3]), geo)
    assert (u[0], w[0]) == pytest.approx((0.2, (1.3 - 0.2 * c30) / s30), rel=1e-14)
    # all three: normal equations diag(2 c^2 + 1, 2 s^2)
    u, w = solve(a, np.array([FULL]), geo)
    assert u[0] == pytest.approx((c30 * (1.3 - 0.7) + 0.2) / (2 * c30**2 + 1), rel=1e-14)
    assert w[0] == pytest.approx(s30 * (1.3 + 0.7) / (2 * s30**2), rel=1e-14)
    # fewer than two channels: nothing to solve
    u, w = solve(np.array([[1.3, 0.0, 0.0]]), np.array([1]), geo)
    assert math.isnan(u[0]) and math.isnan(w[0])


def test_parity_vector_ignores_the_motion_and_sees_one_channel_errors() -> None:
    geo = geometry(NOMINAL)
    p = np.array(geo.parity)
    # (cos th) x (sin th) = (c2 s3 - c3 s2, c3 s1 - c1 s3, c1 s2 - c2 s1) = (-1/2, c30, -1/2)
    c30 = math.cos(math.radians(30))
    assert p == pytest.approx(np.array([-0.5, c30, -0.5]) / math.sqrt(1.25), rel=1e-14)
    for u, w in ((0.0, 9.8), (1.2, 9.7), (-3.0, 9.0)):
        a = np.array([u * math.cos(t) + w * math.sin(t) for t in NOMINAL])
        assert abs(p @ a) < 1e-14


# ----------------------------------------------------------------------------- kalman


def test_kalman_tracks_a_constant_acceleration_exactly_and_restarts_unknown() -> None:
    kf = SpeedKalman(0.003, 1e-4)
    n = 500
    dt = [0.02] * n
    z = [5.0 + 0.4 * 0.02 * k for k in range(n)]  # noise-free ramp
    acc, var = kf.run(dt, z, [True] + [False] * (n - 1))
    assert acc[0] == 0.0 and var[0] == ACCEL0_MPS2**2  # a restart knows the speed only
    assert acc[-1] == pytest.approx(0.4, abs=1e-9)
    assert var[-1] < 1e-4


def test_kalman_reacts_to_a_step_of_acceleration_within_half_a_second() -> None:
    """A step is an infinite jerk: the manoeuvre rule restarts the acceleration estimate
    rather than letting a slow filter lag for seconds."""
    kf = SpeedKalman(0.003, 1e-4)
    t = np.arange(1000) * 0.02
    v = np.where(t < 10.0, 5.0, 5.0 + 0.5 * (t - 10.0))
    z = (np.rint(v * 1000.0) / 1000.0).tolist()  # mm/s like SPEED_REF
    acc, var = kf.run([0.02] * len(z), z, [True] + [False] * (len(z) - 1))
    acc_a = np.array(acc)
    assert np.abs(acc_a[(t > 2.0) & (t < 10.0)]).max() < 0.005
    assert np.abs(acc_a[t > 10.5] - 0.5).max() < 0.01
    assert np.abs(acc_a[t > 11.0] - 0.5).max() < 0.002
    assert np.array(var)[t > 10.5].max() < 0.01**2  # settled again: a_ref is available


# -------------------------------------------------------------------------- alignment


def _samples(ticks: np.ndarray, t: np.ndarray, seq: np.ndarray) -> np.ndarray:
    s = np.zeros(len(ticks), dtype=SAMPLE_DTYPE)
    s["ticks"], s["t"], s["seq"] = ticks, t, seq
    return s


def _speeds(seq: np.ndarray, t: np.ndarray, timestamp: np.ndarray, mm: int) -> np.ndarray:
    s = np.zeros(len(seq), dtype=SPEED_DTYPE)
    s["seq"], s["t"], s["timestamp"], s["speed"] = seq, t, timestamp % 65536, mm
    return s


@pytest.mark.parametrize("receive_times", [True, False])
def test_a_lost_speed_ref_is_noticed_coast_s_after_its_last_frame(receive_times: bool) -> None:
    """Board at 200 Hz from board tick 123456, SPEED_REF at 50 Hz from odometer tick 64000
    (it wraps), 1 ms latency each; SPEED_REF stops after the frame measured at 2.0 s, which
    comes 80 ms late. With receive times its age counts from its measurement (the least
    latency maps the odometer clock); without, from its arrival (the arrival-order fallback).
    """
    s = EstimatorSettings(coast_s=0.4975)  # the limit falls between two samples
    k = np.arange(800)  # 4 s of samples; sample k arrives at 5k ms + 1 ms, seq 2k + 1
    samples = _samples(123456 + 50 * k, 1000.001 + k * 0.005, 2 * k + 1)
    m = np.arange(101)  # frames measured at 20m ms, arriving just before sample 4m
    seq = 8 * m
    t_f = 1000.001 + m * 0.020
    seq[-1], t_f[-1] = 2 * 416, 1000.001 + 2.080  # the last one just before sample 416
    speeds = _speeds(seq, t_f, 64000 + 200 * m, 0)
    if not receive_times:
        samples["t"] = np.nan
        speeds["t"] = np.nan
    ref = ReferenceAcceleration(s)
    ref.buffer(speeds)
    a_ref = ref.push(samples)
    last = k[np.isfinite(a_ref)].max()
    since = 400 if receive_times else 416
    assert last == since + math.floor(s.coast_s / 0.005)
    assert (a_ref[round(s.standstill_s / 0.005) + 2 : last + 1] == 0.0).all()


def test_leaky_min_is_its_definition_and_the_same_in_any_cut() -> None:
    """min over j <= i of x_j + rho (clock_i - clock_j), non-finite x skipped, NaN before the
    first finite one; cut anywhere (the running minimum carried over), the same bytes."""
    rng = np.random.default_rng(2)
    n, rho = 300, 1e-3
    clock = np.cumsum(rng.uniform(0.001, 0.01, n))
    x = rng.normal(0.0, 1e-3, n)
    x[rng.random(n) < 0.1] = np.nan
    x[:7] = np.nan  # nothing to go by at first
    x[50], x[60] = np.inf, -np.inf
    whole, base = leaky_min(x, clock, rho, math.inf)
    for i in range(n):
        terms = [x[j] + rho * (clock[i] - clock[j]) for j in range(i + 1) if np.isfinite(x[j])]
        if terms:
            assert whole[i] == pytest.approx(min(terms), abs=1e-12)
        else:
            assert math.isnan(whole[i])
    cuts = np.cumsum(rng.integers(1, 30, n))
    parts, carried = [], math.inf
    for lo, hi in itertools.pairwise([0, *cuts[cuts < n].tolist(), n]):
        part, carried = leaky_min(x[lo:hi], clock[lo:hi], rho, carried)
        parts.append(part)
    assert np.concatenate(parts).tobytes() == whole.tobytes()
    assert carried == base


# --------------------------------------------------------------------- stuck and latch


def test_stuck_needs_no_change_for_the_window_while_another_channel_changes() -> None:
    det = StuckDetector(window_ticks=100)
    ticks = np.arange(0, 3000, 50)  # 200 Hz
    n = len(ticks)
    code = np.zeros((n, 3), dtype=np.int32)
    code[:, 0] = np.arange(n)  # ch1 changes every sample
    code[:, 1] = 7  # ch2 never changes
    code[:, 2] = np.arange(n) // 10  # ch3 changes every 10 samples (500 ticks)
    present = np.ones((n, 3), dtype=bool)
    stuck = det.push(ticks, code.T, present.T)  # channel-major (3, N)
    assert not stuck[0].any()
    assert stuck[1].tolist() == (ticks >= 100).tolist()  # first seen at 0, quiet from 100
    quiet3 = (ticks % 500) >= 100
    assert stuck[2].tolist() == quiet3.tolist()
    # nothing changes anywhere: a board at rest without noise is not stuck
    det = StuckDetector(window_ticks=100)
    assert not det.push(ticks, np.full((3, n), 5, dtype=np.int32), present.T).any()


def test_latch_holds_an_exclusion_until_healthy_for_recover_ticks() -> None:
    latch = ExclusionLatch(recover_ticks=200)
    ticks = np.arange(0, 1000, 50)
    reason = np.zeros((3, len(ticks)), dtype=np.int64)  # channel-major (3, N)
    reason[1, 4:6] = Reason.STUCK  # ticks 200, 250
    latched, events = latch.push(ticks, ticks / 1e4, np.arange(len(ticks)), reason)
    assert latched[1].tolist() == ((ticks >= 200) & (ticks < 450)).tolist()
    assert not latched[[0, 2]].any()
    assert events["kind"].tolist() == [EventKind.EXCLUDED, EventKind.READMITTED]
    assert events["n"].tolist() == [4, 9] and events["channel"].tolist() == [2, 2]
    assert events["value"][0] == Reason.STUCK


def test_latch_events_come_in_sample_then_channel_order_whole_or_a_sample_at_a_time() -> None:
    ticks = np.arange(0, 500, 50)
    reason = np.zeros((3, len(ticks)), dtype=np.int64)  # channel-major (3, N)
    reason[2, 3] = Reason.STATUS  # tick 150: ch3 and ch1 at once
    reason[0, 3] = Reason.STUCK
    reason[1, 5] = Reason.RESIDUAL  # tick 250, as ch1 and ch3 are readmitted (recover 100)
    ex, re = EventKind.EXCLUDED, EventKind.READMITTED
    expected = [  # (n, kind, channel, value)
        (3, ex, 1, Reason.STUCK),
        (3, ex, 3, Reason.STATUS),
        (5, re, 1, 0),
        (5, ex, 2, Reason.RESIDUAL),
        (5, re, 3, 0),
        (7, re, 2, 0),
    ]
    _, events = ExclusionLatch(recover_ticks=100).push(
        ticks, ticks / 1e4, np.arange(len(ticks)), reason
    )
    assert events[["n", "kind", "channel", "value"]].tolist() == expected
    latch = ExclusionLatch(recover_ticks=100)
    stepped = []
    for i in range(len(ticks)):  # live-sized pushes: the same events, in the same order
        sl = slice(i, i + 1)
        stepped.extend(
            latch.push(ticks[sl], ticks[sl] / 1e4, np.arange(i, i + 1), reason[:, sl])[1]
        )
    assert [(e["n"], e["kind"], e["channel"], e["value"]) for e in stepped] == expected


# --------------------------------------------------------------------------- settings


@pytest.mark.parametrize(
    "key", ["residual_window_s", "a_ref_sigma_mps2", "clock_drift_ppm", "jerk_psd"]
)
def test_estimator_settings_are_validated(key: str) -> None:
    with pytest.raises(ConfigError, match=f"estimator.{key}"):
        config_from_dict({"estimator": {key: -1.0}})
    cfg = config_from_dict({"estimator": {key: 0.25}})
    assert getattr(cfg.estimator, key) == 0.25
