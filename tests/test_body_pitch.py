"""Car-body pitch on the secondary suspension (issue 25) against textbook second-order
physics computed here: the step response's settled value C a, its overshoot
exp(-pi zeta / sqrt(1 - zeta^2)) at t = pi / wd, the ramp's steady lag 2 zeta / wn, the
load's change at stations (drawn N(0, load_step_deg^2): checked over many seeds) and what
the pitched sensors read (frames decoded with protocol.can_codec)."""

from __future__ import annotations

import math
from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate
from devices.emulator.body_pitch import BodyPitch
from devices.errors import ConfigError
from protocol.layout import G0, NOMINAL_SCALE
from tests.helpers import adc_values

C, F, Z = 0.1, 1.2, 0.3  # deg per m/s^2, Hz, damping ratio of these tests
WN = 2 * math.pi * F
WD = WN * math.sqrt(1 - Z * Z)

STEP = f"""
duration_s = 40.0
sample_rate_hz = 100
initial_speed_mps = 10.0
body_modes.enabled = false  # the suspension's pitch alone (issue 25)
[body_pitch]
compliance_deg_per_mps2 = {C}
frequency_hz = {F}
damping_ratio = {Z}
load_step_deg = 0.0
[standstill]
enabled = false
[[train]]
duration_s = 5.0
accel_mps2 = 0.0
[[train]]
duration_s = 35.0
accel_mps2 = 0.8
"""


def sim_of(text: str):
    return simulate(parse_scenario(dedent(text), "pitch.toml"))


def textbook_step(t: np.ndarray) -> np.ndarray:
    """Unit step response of wn^2 / (s^2 + 2 zeta wn s + wn^2) (Ogata's form)."""
    phi = math.acos(Z)
    return 1 - np.exp(-Z * WN * t) / math.sqrt(1 - Z * Z) * np.sin(WD * t + phi)


def test_a_step_in_acceleration_pitches_the_body_as_a_second_order_system():
    sim = sim_of(STEP)
    t, pitch = sim.truth["time_s"], sim.truth["body_pitch_deg"]
    assert np.all(pitch[t < 5.0] == 0.0)  # cruising: no pitch
    settled = C * 0.8  # 0.08 deg nose up
    after = t >= 5.0
    want = settled * textbook_step(t[after] - 5.0)
    assert np.max(np.abs(pitch[after] - want)) < 1e-9
    # overshoot exp(-pi zeta / sqrt(1 - zeta^2)) = 37.2 % at pi / wd = 0.437 s
    overshoot = math.exp(-math.pi * Z / math.sqrt(1 - Z * Z))
    assert overshoot == pytest.approx(0.3723, abs=1e-4)
    peak = int(np.argmax(pitch))
    assert t[peak] - 5.0 == pytest.approx(math.pi / WD, abs=0.006)  # within a sample
    assert pitch[peak] == pytest.approx(settled * (1 + overshoot), rel=2e-3)
    assert pitch[-1] == pytest.approx(settled, rel=1e-9)


def test_a_jerk_limited_ramp_lags_by_two_zeta_over_wn():
    # a = 0.2 t from 5 s on (jerk 0.2 m/s^3 up to 1.0 m/s^2 at 10 s): long after the
    # start of the ramp a second-order system follows a ramp 2 zeta / wn behind
    sim = sim_of(STEP.replace("accel_mps2 = 0.8", "accel_mps2 = 1.0\njerk_mps3 = 0.2"))
    t, pitch = sim.truth["time_s"], sim.truth["body_pitch_deg"]
    lag = 2 * Z / WN  # 0.0796 s
    k = int(np.argmin(np.abs(t - 9.5)))
    assert pitch[k] == pytest.approx(C * 0.2 * (t[k] - 5.0 - lag), rel=1e-3)
    assert pitch[-1] == pytest.approx(C * 1.0, rel=1e-9)


def adc(sim) -> np.ndarray:
    return adc_values(sim.frames)


def test_the_board_on_the_body_reads_the_pitch_as_gradient():
    sim = sim_of(STEP)
    acc = adc(sim)
    t = sim.truth["time_s"]
    k = int(np.argmin(np.abs(t - 39.0)))  # settled: 0.08 deg nose up at 0.8 m/s^2
    beta = C * 0.8
    for ch, th in enumerate((30.0, 0.0, -30.0)):
        a = math.radians(th + beta)
        want = 0.8 * math.cos(a) + G0 * math.sin(a)  # level track, pitched axis
        assert acc[k, ch] == pytest.approx(want, abs=NOMINAL_SCALE), ch
    # ch2 (level) reads 0.8 + g sin(0.08 deg): 1.40 permil of gradient that is not there
    assert (acc[k, 1] - 0.8) / G0 * 1000 == pytest.approx(
        1000 * math.tan(math.radians(beta)), abs=0.01
    )
    off = sim_of(STEP.replace("[body_pitch]", "[body_pitch]\nenabled = false"))
    assert np.all(off.truth["body_pitch_deg"] == 0.0)
    assert adc(off)[k, 1] == pytest.approx(0.8, abs=NOMINAL_SCALE)


STATION = """
duration_s = 120.0
sample_rate_hz = 50
initial_speed_mps = 10.0
seed = {seed}
[body_pitch]
compliance_deg_per_mps2 = 0.1
frequency_hz = 1.2
damping_ratio = 0.3
load_step_deg = 0.05
[standstill]
enabled = false  # no passengers' own steps: the station's load step alone
[[train]]
duration_s = 10.0
accel_mps2 = -1.0
[[train]]
duration_s = 50.0
accel_mps2 = 0.0
[[train]]
duration_s = 5.0
accel_mps2 = 1.0
"""
# brakes to rest at 10 s, stands 10..60 s (a station), departs at 60 s, cruises from 65 s


def pitch_at(seed: int, t: np.ndarray) -> np.ndarray:
    return BodyPitch(parse_scenario(STATION.format(seed=seed), "s.toml")).deg(t)


def test_the_load_pitch_changes_only_during_the_dwell_as_a_ramp():
    t = np.array([9.0, 27.0, 35.0, 57.0, 90.0, 110.0])
    p = pitch_at(1, t)
    assert p[0] == pytest.approx(-0.1, abs=1e-9)  # braking at 1 m/s^2: nose down
    step = p[3]  # doors closed (48 s), settled: the new load pitch
    assert p[4] == pytest.approx(step, abs=1e-9) and p[5] == pytest.approx(step, abs=1e-9)
    assert step != 0.0
    # the ramp runs over 20 %..80 % of the 50 s dwell: 20..50 s at step / 30 s; mid-ramp
    # (35 s) the body is at half the step, 2 zeta / wn behind
    rate = step / 30.0
    assert p[2] == pytest.approx(step / 2 - rate * 2 * 0.3 / (2 * math.pi * 1.2), abs=1e-9)
    assert p[1] == pytest.approx(rate * (27.0 - 20.0 - 2 * 0.3 / (2 * math.pi * 1.2)), abs=1e-9)


def test_the_load_step_at_a_station_has_the_documented_spread():
    # 400 seeds: the sample standard deviation of N(0, 0.05^2) lies within +/-15 % of 0.05
    # (its relative standard error is 1/sqrt(800) = 3.5 %: the bound is over 4 sigma)
    steps = np.array([pitch_at(s, np.array([90.0]))[0] for s in range(400)])
    assert np.std(steps) == pytest.approx(0.05, rel=0.15)
    assert abs(np.mean(steps)) < 4 * 0.05 / math.sqrt(400)


def test_a_short_stop_is_no_station():
    text = STATION.format(seed=3).replace(
        "load_step_deg = 0.05", "load_step_deg = 0.05\nmin_dwell_s = 60.0"
    )
    assert BodyPitch(parse_scenario(text, "s.toml")).deg(np.array([90.0]))[0] == pytest.approx(
        0.0, abs=1e-12
    )


def test_defaults_are_a_metro_car_and_bad_keys_are_named():
    sc = parse_scenario("", "d.toml")
    bp = sc.body_pitch
    assert (bp.enabled, bp.compliance_deg_per_mps2, bp.frequency_hz, bp.damping_ratio) == (
        True,
        0.05,
        1.2,
        0.25,
    )
    with pytest.raises(ConfigError, match=r"body_pitch\.damping_ratio"):
        parse_scenario("[body_pitch]\ndamping_ratio = 1.0\n", "d.toml")
    with pytest.raises(ConfigError, match=r"body_pitch.*stiffness"):
        parse_scenario("[body_pitch]\nstiffness = 1.0\n", "d.toml")
