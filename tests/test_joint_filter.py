"""The joint filter against independent truth: synthetic runs made by tests/truth_runs.py
(plain numpy physics, not the emulator), hand-computed variances, and the settings' bounds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bench.config import Config, EstimatorSettings, config_from_dict
from bench.errors import ConfigError
from bench.fusion import joint_layout as jl
from bench.fusion.estimator import Estimator
from bench.fusion.joint import JointFilter, u_variance_factors
from bench.fusion.least_squares import geometry
from protocol.layout import G0
from tests.truth_runs import Run, make, push_all, scores

NOMINAL = tuple(math.radians(a) for a in (30.0, 0.0, -30.0))


def run_filter(run: Run, config: Config | None = None) -> tuple[np.ndarray, dict]:
    samples, acc, speeds, truth = make(run)
    return push_all(Estimator(config or Config()), samples, acc, speeds), truth


def test_u_variance_per_unit_channel_noise_is_the_uu_element_of_inverse_normal_matrix() -> None:
    # all three: H^T H = diag(sum cos^2, sum sin^2) = diag(2.5, 0.5) -> (H^T H)^-1 uu = 0.4;
    # ch1 + ch3: u = (a1 + a3) / (2 cos 30) -> 2 / (4 * 0.75) = 2/3; ch1 + ch2: u = a2 -> 1
    f = u_variance_factors(geometry(NOMINAL))
    assert f[7] == pytest.approx(0.4, rel=1e-12)
    assert f[5] == pytest.approx(2.0 / 3.0, rel=1e-12)
    assert f[3] == pytest.approx(1.0, rel=1e-12)
    assert f[6] == pytest.approx(1.0, rel=1e-12)
    assert np.isinf(f[[0, 1, 2, 4]]).all()


def test_at_rest_the_gradient_has_no_process_noise_and_u_alone_sets_it() -> None:
    """Standing still for 20 s on +20 permil: no distance, so the gradient's variance never
    grows; it shrinks like 1/N with the accelerometer samples (white noise of 1 mg). The
    bias floor (what calibration leaves) is set to 0 here, to see the filter's own part."""
    cfg = Config(estimator=dataclasses.replace(EstimatorSettings(), bias_sigma_mps2=0.0))
    out, truth = run_filter(Run(duration_s=20.0, track=[(1e9, 20.0)], noise=0.0098), cfg)
    t = truth["time_s"]
    sigma = out["gradient_sigma"]
    late = t > 2.0
    assert np.all(np.diff(sigma[late]) <= 1e-6 * sigma[late][1:])  # no growth at rest
    err = out["gradient_signed"][late] - 20.0
    assert np.isfinite(err).all()
    assert np.max(np.abs(err)) < 0.1
    # sigma(t2) / sigma(t1) ~ sqrt(t1 / t2) once the zero-velocity update pins a
    s5, s20 = sigma[np.searchsorted(t, 5.0)], sigma[-1]
    assert s20 / s5 == pytest.approx(math.sqrt(5.0 / 20.0), rel=0.25)
    assert not out["odometer_suspect"].any() and not out["coasting"][t > 0.1].any()


def test_sigma_never_claims_less_than_the_bias_left_after_calibration() -> None:
    """0.5 mm/s^2 of bias along the track is 1000 * 0.0005 / g = 0.051 permil on level track
    (d gradient / d s = 1000 / g there): the floor however long the train stands."""
    out, _ = run_filter(Run(duration_s=20.0, track=[(1e9, 0.0)], noise=0.0098))
    assert Config().estimator.bias_sigma_mps2 == 0.0005
    floor = 1000.0 * 0.0005 / G0
    assert np.nanmin(out["gradient_sigma"]) >= floor * (1 - 1e-9)
    assert np.nanmin(out["gradient_sigma"]) < floor * 1.2  # and it does reach it at rest


def test_constant_grade_at_speed_known_truth_and_honest_sigma() -> None:
    run = Run(duration_s=60.0, v0=12.0, track=[(1e9, -8.0)], phases=[(60.0, 0.0)])
    out, truth = run_filter(run)
    sc = scores(out["gradient_signed"], truth["gradient_permil"], out["gradient_sigma"])
    assert sc["avail"] > 0.9  # a few seconds to tell a from s while moving from the start
    assert sc["rms"] < 0.1 and sc["max"] < 0.5
    assert sc["cover"] >= 0.95
    assert np.mean(out["gradient_signed"][truth["time_s"] > 10]) < -7.9  # the sign


def test_acceleration_steps_stay_within_0_2_permil_except_while_flagged() -> None:
    run = Run(
        duration_s=40.0,
        v0=10.0,
        jerk=0.0,  # steps: an infinite jerk
        phases=[(10, 0.4), (20, -0.3), (30, 0.4), (40, -0.3)],
        track=[(1e9, 10.0)],
    )
    out, truth = run_filter(run)
    t = truth["time_s"]
    given = np.isfinite(out["gradient_signed"]) & ~out["odometer_suspect"] & (t > 3.0)
    err = np.abs(out["gradient_signed"] - truth["gradient_permil"])
    assert given[t > 3.0].mean() > 0.95
    # the steps at 10, 20 and 30 s: within 0.2 permil wherever the gradient is given
    assert err[given & (t > 5.0)].max() <= 0.2
    # before them the start in motion is still settling (a told from s by the odometer
    # alone): there the error is what its sigma says
    settling = given & (t <= 5.0)
    assert (err[settling] <= 2.0 * out["gradient_sigma"][settling]).all()


def test_wheel_slide_is_gated_flagged_and_kept_out_of_the_gradient() -> None:
    """Braking at -1 m/s^2 from 15 m/s with the odometer reading up to 0.9 m/s low
    (sawtooth, 1 s cycles) between 52 and 60 s."""
    track = [(1e9, 12.0)]
    phases = [(5, 0.0), (20, 1.0), (50, 0.0), (65, -1.0), (70, 0.0)]
    clean, truth = run_filter(Run(duration_s=70.0, phases=phases, track=track))
    slide, _ = run_filter(
        Run(duration_s=70.0, phases=phases, track=track, slides=[(52.0, 60.0, 0.9)])
    )
    t = truth["time_s"]
    window = (t >= 52.0) & (t < 60.0)
    assert slide["odometer_suspect"][window].mean() > 0.5
    assert not clean["odometer_suspect"].any()
    assert not slide["odometer_suspect"][t < 52.0].any()
    assert not slide["odometer_suspect"][t > 63.0].any()  # recovered
    err = np.abs(slide["gradient_signed"] - truth["gradient_permil"])
    given = np.isfinite(err)
    assert np.max(err[given & (t > 10.0)]) < 1.0


CREST = dict(
    duration_s=40.0,
    v0=20.0,
    track=[(300.0, 0.0), (1e9, 30.0)],
    curve_m=80.0,
    odo_noise=0.005,
    odo_quantum=0.02,
    odo_lag=0.03,
)
"""Cruising at 20 m/s into a +30 permil grade over an 80 m vertical curve (R = 2667 m):
the gradient rises 7.5 permil/s for 4 s, and v^2/R = 0.15 m/s^2 presses the car down. The
odometer as a metro's: 5 mm/s noise, 0.02 m/s steps, 30 ms late."""


def test_a_vertical_curve_is_followed_through_v2_over_r() -> None:
    out, truth = run_filter(Run(**CREST))
    t = truth["time_s"]
    curve = (t > 13.0) & (t < 21.0)  # 260..420 m: the curve and 2 s either side
    err = np.abs(out["gradient_signed"] - truth["gradient_permil"])
    given = np.isfinite(err)
    assert truth["gradient_permil"][curve].min() < 1 and truth["gradient_permil"][curve].max() > 29
    assert np.max(err[given & (t > 5.0)]) < 1.0  # never confidently wrong
    assert given[curve].mean() > 0.8  # and mostly given through the curve


def test_without_v2_over_r_the_same_curve_goes_wrong() -> None:
    """What w is for: with the w blocks switched off, the curve has to come from u and the
    odometer alone, which tell a gradient that starts to change from a train that starts
    to accelerate only after seconds; meanwhile the gradient is several permil off."""
    blind = Config(estimator=dataclasses.replace(EstimatorSettings(), w_block_s=0.0))
    out, truth = run_filter(Run(**CREST), blind)
    t = truth["time_s"]
    err = np.abs(out["gradient_signed"] - truth["gradient_permil"])
    given = np.isfinite(err)
    assert np.max(err[given & (t > 5.0)]) > 2.0


def test_the_grade_rate_stays_within_the_sharpest_curve_the_line_has() -> None:
    """vertical_radius_min_m bounds k = g / R: whatever w does (here a 2 m/s^2 bump, as a
    rail joint might give), the filter's grade rate never exceeds g / 500 m."""
    cfg = Config()
    geo = geometry(cfg.angles_rad)
    f = JointFilter(cfg, geo)
    n = 2000
    b = np.arange(n) * 0.005
    w = np.full(n, G0)
    w[1000:1100] += 2.0
    anchors = np.arange(0, n, 4)
    frames = (anchors, b[anchors], np.full(len(anchors), 20.0), anchors == 0, anchors < 0)
    f.push(b, np.zeros(n), w, np.full(n, 7), np.zeros(n), np.zeros(n, np.int8), frames)
    assert abs(f.x[jl.IK]) <= G0 / 500.0 + 1e-12
    assert cfg.estimator.vertical_radius_min_m == 500.0


def test_without_speed_ref_it_withholds_and_coasts_flagged() -> None:
    phases = [(5, 0.0), (20, 1.0), (40, 0.0)]
    out, truth = run_filter(
        Run(duration_s=40.0, phases=phases, track=[(1e9, 5.0)], dropouts=[(25.0, 35.0)])
    )
    t = truth["time_s"]
    gap = (t > 25.6) & (t < 35.0)
    assert out["coasting"][gap].all() and not out["coasting"][(t > 1) & (t < 25)].any()
    assert out["gradient_sigma"][gap][-1] > out["gradient_sigma"][gap][0]  # sigma grows
    err = np.abs(out["gradient_signed"] - truth["gradient_permil"])[gap]
    assert np.all(err[np.isfinite(err)] <= 1.0)  # withheld rather than wrong


def test_the_limit_withholds_by_the_sigma_it_reports() -> None:
    out, _ = run_filter(Run(duration_s=20.0, v0=12.0, track=[(1e9, 3.0)]))
    limit = Config().gradient_sigma_limit_permil
    given = np.isfinite(out["gradient_signed"])
    assert np.all(out["gradient_sigma"][given] <= limit)
    assert np.all(~(out["gradient_sigma"][~given] <= limit))
    assert given.any() and (~given).any()


def test_one_kernel_call_equals_many_one_sample_calls() -> None:
    cfg = Config()
    geo = geometry(cfg.angles_rad)
    rng = np.random.default_rng(3)
    n = 400
    b = np.arange(n) * 0.005
    u = G0 * 0.01 + 0.01 * rng.standard_normal(n)
    w = G0 + 0.01 * rng.standard_normal(n)
    mask = np.full(n, 7)
    res = 0.001 * rng.standard_normal(n)
    latched = np.zeros(n, dtype=np.int8)
    anchors = np.arange(3, n, 4)
    frames = (anchors, b[anchors] - 0.002, 0.5 + 0.0 * b[anchors], anchors == 3, anchors < 0)
    whole = JointFilter(cfg, geo).push(b, u, w, mask, res, latched, frames)
    one = JointFilter(cfg, geo)
    parts = []
    for i in range(n):
        sel = anchors == i
        fr = (np.zeros(sel.sum(), np.int64), *(f[sel] for f in frames[1:]))
        parts.append(one.push(b[i : i + 1], u[i : i + 1], w[i : i + 1], mask[i : i + 1],
                              res[i : i + 1], latched[i : i + 1], fr))  # fmt: skip
    for name in ("gradient", "sigma", "suspect", "coasting", "accel"):
        cut = np.concatenate([getattr(p, name) for p in parts])
        assert getattr(whole, name).tobytes() == cut.tobytes(), name


def test_state_layout_sizes() -> None:
    x, cov, m = jl.new_state(np.zeros(jl.P_SIZE))
    assert x.shape == (jl.NX,) and cov.shape == (jl.NX, jl.NX) and m.shape == (jl.M_SIZE,)


@pytest.mark.parametrize("value", [0.0, -1.0, 101.0, float("nan")])
def test_sigma_limit_is_bounded(value: float) -> None:
    with pytest.raises(ConfigError, match="gradient_sigma_limit_permil"):
        config_from_dict({"fusion": {"gradient_sigma_limit_permil": value}})


def test_settings_round_trip_and_latency_may_be_zero() -> None:
    cfg = config_from_dict(
        {"fusion": {"gradient_sigma_limit_permil": 0.8}, "estimator": {"odometer_latency_s": 0.0}}
    )
    assert cfg.gradient_sigma_limit_permil == 0.8
    assert cfg.estimator == dataclasses.replace(EstimatorSettings(), odometer_latency_s=0.0)
    with pytest.raises(ConfigError, match="accel_psd"):
        config_from_dict({"estimator": {"accel_psd": 0.0}})
