"""The model's body pitch under acceleration (issue 26): on an emulated run whose car body
pitches with a known compliance and whose wheel reads a known error, the smoother finds
both within its own two sigma and keeps the pitch out of the gradient.

Expectations are the emulator's: the compliance and wheel error written into the scenario
here, the track's gradient in its truth, and the physics of a model without the state (a
body pitched C a reads as an acceleration g C a larger, which the wheel-scale error E then
absorbs: E off by g C)."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from bench.config import config_from_dict
from bench.fusion.model.log import ModelLog, Smoothed
from bench.pipeline.steps import Pipeline
from bench.replay.run import run_steps
from devices.base import SourceBatch
from devices.emulator import calibration_toml, simulate
from devices.emulator.scenario import parse_scenario

GRADIENT = 12.0  # permil, the whole line
WHEEL = 0.02  # the odometer reads 2 % high
COMPLIANCE = 0.1  # deg per m/s^2, nose up accelerating (twice the emulator's default)
SCENARIO = f"""
description = "two acceleration phases and a braking, the body pitching {COMPLIANCE} deg per m/s^2"
seed = 7
duration_s = 70.0
sample_rate_hz = 100
speed_ref = true
jerk_mps3 = 0.8
track = [{{ length_m = 5000.0, gradient_permil = {GRADIENT} }}]
train = [
    {{ duration_s = 6.0 }},
    {{ duration_s = 11.0, accel_mps2 = 1.0 }},
    {{ duration_s = 9.0 }},
    {{ duration_s = 13.0, accel_mps2 = -0.9 }},
    {{ duration_s = 4.0 }},
    {{ duration_s = 13.0, accel_mps2 = 0.8 }},
    {{ duration_s = 14.0 }},
]
[odometer]
lag_s = 0.03
noise_mps = 0.005
wheel_diameter_error = {WHEEL}
[body_pitch]
compliance_deg_per_mps2 = {COMPLIANCE}
frequency_hz = 1.2
damping_ratio = 0.25
[body_modes]
enabled = false  # the model takes the modes as white noise per block (docs/ESTIMATOR.md)
"""


@pytest.fixture(scope="module")
def run() -> tuple[ModelLog, object, np.ndarray, np.ndarray]:
    """(the model's log of the run, the bench config, result rows, truth gradient)."""
    sc = parse_scenario(SCENARIO, "pitch.toml")
    sim = simulate(sc)
    config = config_from_dict(tomllib.loads(calibration_toml(sc)), source="pitch calibration")
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
    return log, config, np.concatenate(rows).astype(np.int64), sim.truth["gradient_permil"]


def _smooth(run, **prm: float) -> Smoothed:  # type: ignore[no-untyped-def]
    log, config, _, _ = run
    return log.smooth(config, **prm)


def test_the_compliance_and_the_wheel_error_are_found_within_two_sigma(run) -> None:  # type: ignore[no-untyped-def]
    sm = _smooth(run)
    c, cs = sm.compliance_deg_per_mps2, sm.compliance_sigma_deg_per_mps2
    assert abs(c - COMPLIANCE) <= 2.0 * cs, sm.describe()
    # what 70 s at 100 Hz of 1 mg channels can tell: C only through the normal axis (the
    # along-track one sees (1 + g C) / (1 + E) alone), 1-sigma about 0.03 deg per m/s^2
    # here; issue 26's 10 % needs a quieter or faster board (docs/ESTIMATOR.md)
    assert 0.0 < cs < 0.04, sm.describe()
    assert abs(sm.wheel_scale - WHEEL) <= 2.0 * sm.wheel_scale_sigma, sm.describe()
    assert 0.0 < sm.wheel_scale_sigma < 0.006, sm.describe()


def test_without_the_state_the_wheel_error_absorbs_g_times_the_compliance(run) -> None:  # type: ignore[no-untyped-def]
    # C held at 0: the along-track axis reads the acceleration 1 + g C too large, which the
    # odometer's scale then takes: E = (1 + WHEEL) / (1 + g C) - 1, by hand 0.278 %
    g_c = 9.80665 * math.radians(COMPLIANCE)
    sm = _smooth(run, compliance0_rad_per_mps2=0.0)
    assert sm.compliance_deg_per_mps2 == 0.0
    assert sm.wheel_scale == pytest.approx((1.0 + WHEEL) / (1.0 + g_c) - 1.0, abs=0.002)


def test_the_body_pitch_stays_out_of_the_smoothed_gradient(run) -> None:  # type: ignore[no-untyped-def]
    _, _, rows, truth = run
    sm = _smooth(run)
    given = np.isfinite(sm.smoothed)
    err = sm.smoothed[given] - truth[rows[given]]
    # 0.1 deg per m/s^2 at 1 m/s^2 is 1.75 permil of pitch at each change of acceleration
    assert given.mean() > 0.995
    assert float(np.sqrt(np.mean(err**2))) < 0.03
    assert float(np.abs(err).max()) < 0.1  # 0.18 with C held at 0
