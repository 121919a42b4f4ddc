"""The model's vertical-curve jumps (issue 26, bench.fusion.model.jump): on emulated runs the
test finds a curve's start and end where the track has them, K follows from there, and a
run on one constant gradient gives no jump.

Expectations are the emulator's: the track written here (a curve's start and end are at
its boundary -+ half its length, its K = dS/dx = g (dG / 1000) / length between them,
cos(alpha) ~ 1) and the positions in its truth. The kernels' own tests (the correction is
the filter that knew the step, on a linear model) are in tests/test_model.py, which also
runs uncompiled."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from bench.config import config_from_dict
from bench.fusion.model import state
from bench.fusion.model.log import ModelLog, Smoothed
from bench.pipeline.steps import Pipeline
from bench.replay.run import run_steps
from devices.base import SourceBatch
from devices.emulator import calibration_toml, simulate
from devices.emulator.scenario import parse_scenario

BOUNDARY = 400.0  # m, where the gradient changes
CURVE = 60.0  # m, the vertical curve's length
STEP = 20.0  # permil, the change
SPEED = 10.0  # m/s: slow, so the normal axis's v^2 K / c is weak and K's walk follows late
G = 9.80665
K_CURVE = G * STEP / 1000.0 / CURVE  # dS/dx inside the curve, m/s^2 per m
TOLERANCE_M = 10.0  # an onset is placed within this of the track's (1 s at 10 m/s)

HEAD = """
seed = 11
sample_rate_hz = 100
speed_ref = true
jerk_mps3 = 0.8
"""
TABLES = """
[odometer]
lag_s = 0.03
noise_mps = 0.005
[body_modes]
enabled = false
"""
VIBRATION = """
[vibration]  # the demo's: a 2.5 Hz bounce and broadband, growing with the speed
vertical_mps2 = 0.25
longitudinal_mps2 = 0.08
frequency_hz = 2.5
broadband_vertical_mps2 = 0.15
broadband_longitudinal_mps2 = 0.05
broadband_low_hz = 0.5
broadband_high_hz = 40.0
reference_speed_mps = 20.0
"""
CURVED = (
    f"""
description = "cruise at {SPEED} m/s over a {STEP} permil change on a {CURVE} m vertical curve"
duration_s = 130.0
initial_speed_mps = {SPEED}
vertical_curve_m = {CURVE}
vertical_curve_accel = true
track = [{{ length_m = {BOUNDARY}, gradient_permil = 0.0 }},
         {{ length_m = 5000.0, gradient_permil = {STEP} }}]
train = [{{ duration_s = 130.0 }}]
"""
    + HEAD
    + TABLES
)
LEVEL = (
    """
description = "four minutes on one 12 permil gradient: three acceleration phases, brakings, a stop"
duration_s = 240.0
track = [{ length_m = 20000.0, gradient_permil = 12.0 }]
train = [
    { duration_s = 5.0 },
    { duration_s = 15.0, accel_mps2 = 1.0 },
    { duration_s = 40.0 },
    { duration_s = 10.0, accel_mps2 = -0.9 },
    { duration_s = 30.0 },
    { duration_s = 6.0, accel_mps2 = -1.0 },
    { duration_s = 15.0 },
    { duration_s = 12.0, accel_mps2 = 0.8 },
    { duration_s = 60.0 },
    { duration_s = 16.0, accel_mps2 = -0.8 },
    { duration_s = 31.0 },
]
"""
    + HEAD
    + TABLES
    + VIBRATION
)


def _run(text: str) -> tuple[Smoothed, np.ndarray, np.ndarray]:
    """(the model over the emulated run, result rows, the truth)."""
    sc = parse_scenario(text, "jump.toml")
    sim = simulate(sc)
    config = config_from_dict(tomllib.loads(calibration_toml(sc)), source="jump calibration")
    pipeline = Pipeline(config)
    log = ModelLog()
    pipeline.estimator.log = log  # type: ignore[attr-defined]  # the real Estimator
    counter0 = int(sim.truth["counter"][0])
    rows = []
    frames = sim.frames
    batches = (SourceBatch(frames[i : i + 4096]) for i in range(0, len(frames), 4096))
    for step in run_steps(pipeline, batches):
        if len(step.results):
            rows.append(step.results["n"] - counter0)
    return log.smooth(config), np.concatenate(rows).astype(np.int64), sim.truth


def _onsets(sm: Smoothed, rows: np.ndarray, truth: np.ndarray) -> list[tuple[float, float]]:
    """(position m of the onset found, K's step) of every jump found."""
    found = np.flatnonzero(sm.jumps[:, 1] >= 0)
    out = []
    for k in found:
        onset = int(k - sm.jumps[k, 1]) * sm.block  # the onset block's first sample
        out.append((float(truth["position_m"][rows[onset]]), float(sm.jumps[k, 0])))
    return out


@pytest.fixture(scope="module")
def curved() -> tuple[Smoothed, np.ndarray, np.ndarray]:
    return _run(CURVED)


def test_a_curves_start_and_end_are_found_where_the_track_has_them(curved) -> None:  # type: ignore[no-untyped-def]
    sm, rows, truth = curved
    onsets = _onsets(sm, rows, truth)
    start, end = BOUNDARY - CURVE / 2, BOUNDARY + CURVE / 2
    assert len(onsets) == 2, onsets
    (x1, k1), (x2, k2) = onsets
    assert abs(x1 - start) <= TOLERANCE_M and abs(x2 - end) <= TOLERANCE_M, onsets
    # each step has K's change's sign; its size is the estimate given the prior N(0, s^2)
    # and the evidence of the blocks up to the detection, shrunk towards 0: less than K's
    # change, more than a quarter of it
    assert 0.25 * K_CURVE < k1 < 1.2 * K_CURVE and 0.25 * K_CURVE < -k2 < 1.2 * K_CURVE


def test_k_and_the_gradient_follow_the_curve_once_found(curved) -> None:  # type: ignore[no-untyped-def]
    sm, rows, truth = curved
    pos = truth["position_m"][rows]
    blk = np.arange(len(rows)) // sm.block
    k = sm.states[blk, state.K]
    k_sig = sm.states_sigma[blk, state.K]
    # inside the curve, away from its ends by the tolerance: K within 2 sigma of the track's
    inside = (pos > BOUNDARY - CURVE / 2 + TOLERANCE_M) & (pos < BOUNDARY + CURVE / 2 - TOLERANCE_M)
    assert inside.sum() > 200
    assert np.mean(np.abs(k[inside] - K_CURVE) <= 2.0 * k_sig[inside]) >= 0.95
    # the gradient given (filtered: what a live run shows) within 2 of its sigma 95 % of
    # the time from the curve's start on, and never wrong by 1 permil (before: K's walk
    # followed the curve late)
    grad = truth["gradient_permil"][rows]
    after = pos > BOUNDARY - CURVE / 2
    given = after & np.isfinite(sm.filtered)
    err = np.abs(sm.filtered[given] - grad[given])
    assert given.sum() > 0.5 * after.sum()
    assert np.mean(err <= 2.0 * sm.filtered_sigma[given]) >= 0.95
    assert err.max() < 1.0


def test_one_gradient_gives_no_jump() -> None:
    sm, rows, truth = _run(LEVEL)
    assert np.all(truth["gradient_permil"] == 12.0)
    assert _onsets(sm, rows, truth) == []
    assert len(sm.jumps) == len(sm.states)
