"""The realistic parts of the virtual board against physics computed here by hand.

Jerk-limited phases, the odometer (wheel slide/slip, quantisation, latency), rigid-body car
vibration, v^2/R on vertical curves and bias drift with temperature. As in
test_emulator_physics.py nothing here calls the emulator's model: frames are decoded with
protocol.can_codec and compared with plain formulas.
"""

from __future__ import annotations

import math
import tomllib
from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import calibration_toml, parse_scenario, simulate
from devices.errors import ConfigError
from protocol.layout import G0, NOMINAL_SCALE
from protocol.records import BoardStatus, SpeedRef
from tests.helpers import adc_values, records

S30 = math.sin(math.radians(30.0))
C30 = math.cos(math.radians(30.0))


def sim_of(text: str):
    return simulate(parse_scenario(dedent(text), "realism.toml"))


def adc(sim) -> np.ndarray:
    """(n, 3) accelerations from the ADC frames at the nominal scale (fault-free runs: the
    frames come in sample order, ch1, ch2, ch3)."""
    return adc_values(sim.frames)


def speeds(sim) -> tuple[np.ndarray, np.ndarray]:
    """(send time s, reported speed m/s) of every SPEED_REF frame."""
    t, v = [], []
    for f, rec in zip(sim.frames, records(sim.frames), strict=True):
        if isinstance(rec, SpeedRef):
            t.append(float(f["t"]))
            v.append(rec.speed / 1000.0)
    return np.array(t), np.array(v)


# ----------------------------------------------------------------------- jerk-limited phases

JERK = """
duration_s = 40.0
sample_rate_hz = 100
initial_speed_mps = 10.0
jerk_mps3 = 0.5
[[train]]
duration_s = 5.0
[[train]]
duration_s = 30.0
accel_mps2 = -1.0
"""


def hand_jerk_brake(t: float) -> tuple[float, float, float]:
    """10 m/s for 5 s; brake demand -1 at 0.5 m/s^3: ramp 2 s (v 10 -> 9, x +19.333), hold
    -1 until v = a^2 / 2j = 1 m/s (8 s, x +40), ease off 2 s (v 1 -> 0, x +0.667): at rest
    from 17 s at 110 m."""
    if t < 5.0:
        return 0.0, 10.0, 10.0 * t
    if t < 7.0:
        s = t - 5.0
        return -0.5 * s, 10.0 - 0.25 * s * s, 50.0 + 10.0 * s - 0.5 * s**3 / 6.0
    if t < 15.0:
        s = t - 7.0
        return -1.0, 9.0 - s, 50.0 + 20.0 - 4.0 / 6.0 + 9.0 * s - 0.5 * s * s
    if t < 17.0:
        s = t - 15.0
        x = 50.0 + 20.0 - 4.0 / 6.0 + 40.0 + s - 0.5 * s * s + 0.5 * s**3 / 6.0
        return -1.0 + 0.5 * s, 1.0 - s + 0.25 * s * s, x
    return 0.0, 0.0, 110.0


def test_jerk_limited_braking_eases_off_into_the_stop():
    tr = sim_of(JERK).truth
    for k in range(0, len(tr), 7):
        a, v, x = hand_jerk_brake(k / 100)
        assert tr["accel_mps2"][k] == pytest.approx(a, abs=1e-9), k
        assert tr["speed_mps"][k] == pytest.approx(v, abs=1e-9), k
        assert tr["position_m"][k] == pytest.approx(x, abs=1e-8), k
    jerk = np.diff(tr["accel_mps2"]) * 100
    assert np.abs(jerk).max() <= 0.5 + 1e-9  # never steps


def test_a_phase_shorter_than_its_ramp_ends_part_way():
    tr = sim_of(
        """
        duration_s = 6.0
        sample_rate_hz = 100
        jerk_mps3 = 0.5
        [[train]]
        duration_s = 1.0
        accel_mps2 = 1.0
        [[train]]
        duration_s = 5.0
        """
    ).truth
    # up at 0.5 m/s^3 for 1 s (a = 0.5), then down at 0.5 m/s^3 for 1 s back to 0
    assert tr["accel_mps2"][100] == pytest.approx(0.5, abs=1e-12)
    assert tr["accel_mps2"][150] == pytest.approx(0.25, abs=1e-12)
    assert tr["accel_mps2"][200:].max() == pytest.approx(0.0, abs=1e-12)
    # speed gained: two triangles' worth, 0.5 * 2 s * 0.5 m/s^2
    assert tr["speed_mps"][300] == pytest.approx(0.5, abs=1e-12)


def test_per_phase_jerk_overrides_and_zero_means_a_step():
    tr = sim_of(
        """
        duration_s = 4.0
        sample_rate_hz = 100
        jerk_mps3 = 0.5
        [[train]]
        duration_s = 2.0
        accel_mps2 = 1.0
        jerk_mps3 = 0.0
        [[train]]
        duration_s = 2.0
        accel_mps2 = 0.0
        jerk_mps3 = 2.0
        """
    ).truth
    assert tr["accel_mps2"][1] == 1.0  # stepped
    assert tr["accel_mps2"][225] == pytest.approx(0.5, abs=1e-12)  # 2 m/s^3 down
    assert tr["accel_mps2"][260] == 0.0


# ----------------------------------------------------------------------- odometer

SLIDE = """
duration_s = 20.0
sample_rate_hz = 50
initial_speed_mps = 20.0
[[train]]
duration_s = 2.0
[[train]]
duration_s = 12.0
accel_mps2 = -1.0
[[train]]
duration_s = 6.0
accel_mps2 = 0.8
[odometer]
slide_depth_mps = 0.6
slide_period_s = 1.0
slide_min_decel_mps2 = 0.3
slip_depth_mps = 0.2
slip_period_s = 0.5
"""


def hand_saw(tau: float, period: float) -> float:
    phase = tau / period - math.floor(tau / period)
    return phase / 0.75 if phase < 0.75 else (1.0 - phase) / 0.25


def test_wheel_slide_and_slip_are_wsp_sawtooth_errors():
    t, v = speeds(sim_of(SLIDE))
    first_brake = 2.0037 + 0.0  # first SPEED_REF at 3.7 ms, every 20 ms: 2.0037 s
    first_motor = 14.0037
    for ti, vi in zip(t, v, strict=True):
        if ti < 2.0:
            true, err = 20.0, 0.0
        elif ti < 14.0:
            true = 20.0 - (ti - 2.0)
            err = -min(0.6 * hand_saw(ti - first_brake, 1.0), true)
        else:
            true = 8.0 + 0.8 * (ti - 14.0)
            err = 0.2 * hand_saw(ti - first_motor, 0.5)
        assert vi == pytest.approx(round((true + err) * 1000) / 1000, abs=1.01e-3), ti
    assert v.min() > 0.0
    braking = (t > 2.0) & (t < 14.0)
    true_b = 20.0 - (t[braking] - 2.0)
    assert (true_b - v[braking]).max() == pytest.approx(0.6, abs=0.02)  # up to 0.6 m/s low


def test_the_odometer_truth_says_what_each_speed_ref_got_wrong():
    sim = sim_of(SLIDE)
    t, v = speeds(sim)
    od = sim.odometer
    assert len(od) == len(t)  # no fault: every frame the odometer sent arrived
    assert np.allclose(od["reported_mps"], v)
    assert np.allclose(od["measured_s"], od["time_s"])  # lag_s = 0
    tm = od["measured_s"]
    true = np.where(tm < 2.0, 20.0, np.where(tm < 14.0, 20.0 - (tm - 2.0), 8.0 + 0.8 * (tm - 14.0)))
    assert np.allclose(od["train_speed_mps"], true, atol=1e-9)
    braking = (tm > 2.0) & (tm < 14.0)
    assert od["wheel_error_mps"][braking].min() == pytest.approx(-0.6, abs=0.02)
    assert (od["wheel_error_mps"][tm < 2.0] == 0.0).all()
    assert np.allclose(od["reported_mps"], np.round(true + od["wheel_error_mps"], 3), atol=1e-9)


@pytest.mark.parametrize("e", [0.03, -0.02])
def test_a_wheel_diameter_error_scales_every_reported_speed(e: float):
    """A wheel worn 3 % smaller than configured: the odometer takes each turn for 3 % more
    than it rolls and reports the wheel's speed times (1 + e), slide and slip included (a
    wheel too large, e < 0, reports low); the odometer truth says e."""
    sim = sim_of(SLIDE + f"wheel_diameter_error = {e}\n")
    _t, v = speeds(sim)
    od = sim.odometer
    tm = od["measured_s"]
    true = np.where(tm < 2.0, 20.0, np.where(tm < 14.0, 20.0 - (tm - 2.0), 8.0 + 0.8 * (tm - 14.0)))
    wheel = true + od["wheel_error_mps"]
    assert np.allclose(v, np.round(wheel * (1.0 + e), 3), atol=1e-9)
    assert v[0] == pytest.approx(20.0 * (1.0 + e), abs=1e-9)  # 20.6 (19.6) m/s at 20 m/s
    assert (od["wheel_diameter_error"] == e).all()
    assert np.array_equal(od["train_speed_mps"], sim_of(SLIDE).odometer["train_speed_mps"])
    with pytest.raises(ConfigError, match=r"odometer\.wheel_diameter_error: must be <= 0\.05"):
        sim_of(SLIDE + "wheel_diameter_error = 0.06\n")


def test_slide_only_inside_the_low_adhesion_window():
    text = SLIDE.replace("slip_period_s = 0.5", "slip_period_s = 0.5\nlow_adhesion_end_s = 6.0")
    t, v = speeds(sim_of(text))
    late = t >= 6.0
    true = np.where(t < 14.0, 20.0 - (t - 2.0), 8.0 + 0.8 * (t - 14.0))
    assert np.abs(v[late] - true[late]).max() <= 1e-3 + 1e-9
    assert np.abs(v[~late & (t > 2.2)] - true[~late & (t > 2.2)]).max() > 0.3


def test_odometer_quantisation_and_latency():
    t, v = speeds(
        sim_of(
            """
            duration_s = 10.0
            sample_rate_hz = 50
            [[train]]
            duration_s = 10.0
            accel_mps2 = 0.37
            [odometer]
            lag_s = 0.25
            resolution_mps = 0.05
            """
        )
    )
    for ti, vi in zip(t, v, strict=True):
        true = 0.37 * max(ti - 0.25, 0.0)  # the speed 0.25 s ago
        assert vi == pytest.approx(round(true / 0.05) * 0.05, abs=1e-9), ti
    assert len(np.unique(np.round(v / 0.05, 6) % 1)) == 1  # whole steps only


# ----------------------------------------------------------------------- car-body vibration

VIB = """
duration_s = 8.0
sample_rate_hz = 200
body_modes.enabled = false  # the body's tone alone (issue 25)
initial_speed_mps = {v}
[board]
antialias_filter = false  # the tones below are unfiltered (issue 25)
[standstill]
enabled = false  # the body's tone alone
[vibration]
vertical_mps2 = 0.25
longitudinal_mps2 = 0.08
frequency_hz = 2.5
longitudinal_phase_deg = 90.0
reference_speed_mps = 20.0
speed_exponent = 1.0
"""


def body_axes(acc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x from ch2, x from ch1+ch3, z) at the nominal angles +30, 0, -30 degrees."""
    x2 = acc[:, 1]
    x13 = (acc[:, 0] + acc[:, 2]) / (2.0 * C30)
    z = (acc[:, 0] - acc[:, 2]) / (2.0 * S30)
    return x2, x13, z


@pytest.mark.parametrize("speed", [20.0, 10.0])
def test_body_vibration_is_one_rigid_motion_seen_by_all_three_channels(speed: float):
    acc = adc(sim_of(VIB.format(v=speed)))
    t = np.arange(len(acc)) / 200.0
    k = speed / 20.0  # grows linearly with speed
    want_x = k * 0.08 * np.sin(2 * math.pi * 2.5 * t + math.pi / 2)
    want_z = G0 + k * 0.25 * np.sin(2 * math.pi * 2.5 * t)
    x2, x13, z = body_axes(acc)
    lsb = NOMINAL_SCALE
    assert np.abs(x2 - want_x).max() <= lsb
    assert np.abs(x13 - want_x).max() <= 2 * lsb  # the pitched pair sees the same x
    assert np.abs(z - want_z).max() <= 2 * lsb


def test_no_vibration_at_standstill():
    acc = adc(sim_of(VIB.format(v=0.0)))
    assert (acc == acc[0]).all()
    assert acc[0, 1] == 0.0 and acc[0, 0] == pytest.approx(G0 * S30, abs=NOMINAL_SCALE)


def test_broadband_vibration_has_its_rms_inside_its_band():
    acc = adc(
        sim_of(
            """
            duration_s = 60.0
            sample_rate_hz = 200
            seed = 5
            initial_speed_mps = 20.0
            body_modes.enabled = false  # the band alone (issue 25)
            [vibration]
            broadband_vertical_mps2 = 0.1
            broadband_longitudinal_mps2 = 0.04
            broadband_low_hz = 5.0
            broadband_high_hz = 30.0
            """
        )
    )
    x2, x13, z = body_axes(acc)
    assert np.abs(x2 - x13).max() <= 3 * NOMINAL_SCALE  # consistent across channels
    for sig, rms in ((z - G0, 0.1), (x2, 0.04)):
        assert np.sqrt(np.mean(sig**2)) == pytest.approx(rms, rel=0.1)
        power = np.abs(np.fft.rfft(sig)) ** 2
        f = np.fft.rfftfreq(len(sig), 1 / 200.0)
        inside = (f >= 4.9) & (f <= 30.1)
        assert power[inside].sum() / power.sum() > 0.98  # broadband, but in its band
        assert (power[inside] > 0).mean() > 0.5  # many lines, not a few tones
    assert np.corrcoef(z - G0, x2)[0, 1] == pytest.approx(0.0, abs=0.1)  # independent axes


# ----------------------------------------------------------------------- v^2 / R

CURVE = """
duration_s = 20.0
sample_rate_hz = 100
initial_speed_mps = 20.0
vertical_curve_accel = true
body_modes.enabled = false  # v^2/R alone (issue 25)
[standstill]
enabled = false  # v^2/R alone
[[track]]
length_m = 200.0
gradient_permil = 0.0
[[track]]
length_m = 500.0
gradient_permil = 20.0
vertical_curve_m = 200.0
"""


def test_vertical_curve_adds_v_squared_over_r_normal_to_the_track():
    sim = sim_of(CURVE)
    acc = adc(sim)
    x = sim.truth["position_m"]
    for k in range(0, len(acc), 13):
        g_permil = 0.0 if x[k] < 100 else (20.0 if x[k] >= 300 else 20.0 * (x[k] - 100) / 200)
        alpha = math.atan(g_permil / 1000.0)
        on_curve = 100 < x[k] < 300
        # 1/R = d(alpha)/dx = (0.02 / 200 m) / (1 + tan^2)
        a_n = 20.0**2 * (0.02 / 200.0) / (1.0 + (g_permil / 1000) ** 2) if on_curve else 0.0
        fx, fz = G0 * math.sin(alpha), G0 * math.cos(alpha) + a_n
        for ch, th in enumerate((30.0, 0.0, -30.0)):
            want = fx * math.cos(math.radians(th)) + fz * math.sin(math.radians(th))
            assert acc[k, ch] == pytest.approx(want, abs=NOMINAL_SCALE), (k, ch)
    # about 0.04 m/s^2 on a 10 km radius at 20 m/s, halved by sin 30 on ch1
    plain = sim_of(CURVE.replace("vertical_curve_accel = true", "vertical_curve_accel = false"))
    mid = int(np.argmin(np.abs(x - 200.0)))
    assert acc[mid, 0] - adc(plain)[mid, 0] == pytest.approx(0.04 * S30, rel=1e-3)
    # a real car always feels it: a scenario that does not say so gets it too
    default = sim_of(CURVE.replace("vertical_curve_accel = true\n", ""))
    assert np.array_equal(adc(default), acc)


# ----------------------------------------------------------------------- temperature drift

TEMP = """
duration_s = 300.0
sample_rate_hz = 50
[body_pitch]
enabled = false
[standstill]
enabled = false
[[channels]]
bias_mps2 = 0.002
scale_error = 0.001
bias_tempco_mps2_per_k = 0.0005
[[channels]]
[[channels]]
bias_tempco_mps2_per_k = -0.0002
[board]
temperature_c = 20
temperature_end_c = 40.0
temperature_tau_s = 100.0
"""


def test_bias_drifts_with_the_board_temperature_it_reports():
    sim = sim_of(TEMP)
    acc = adc(sim)
    for k in range(0, len(acc), 97):
        t = k / 50.0
        rise = 20.0 * (1.0 - math.exp(-t / 100.0))
        want1 = G0 * S30 * 1.001 + 0.002 + 0.0005 * rise
        want3 = -G0 * S30 - 0.0002 * rise
        assert acc[k, 0] == pytest.approx(want1, abs=NOMINAL_SCALE)
        assert acc[k, 2] == pytest.approx(want3, abs=NOMINAL_SCALE)
        assert acc[k, 1] == 0.0
    temps = [rec.temperature for rec in records(sim.frames) if isinstance(rec, BoardStatus)]
    assert len(temps) == 3000
    for k, temp in enumerate(temps):
        t = 0.0005 + 0.1 * k  # BOARD_STATUS k describes this instant
        assert temp == round(40.0 - 20.0 * math.exp(-t / 100.0)), k


def test_calibration_sheet_undoes_scale_error_and_bias_at_the_start_temperature():
    sc = parse_scenario(dedent(TEMP), "t.toml")
    cal = tomllib.loads(calibration_toml(sc))["channels"]
    assert cal[0]["offset"] == pytest.approx(0.002 / NOMINAL_SCALE, rel=1e-12)
    assert cal[0]["scale"] == pytest.approx(NOMINAL_SCALE / 1.001, rel=1e-12)
    assert cal[1]["offset"] == 0.0 and cal[1]["scale"] == NOMINAL_SCALE
    code = (G0 * S30 * 1.001 + 0.002) / NOMINAL_SCALE
    assert (code - cal[0]["offset"]) * cal[0]["scale"] == pytest.approx(G0 * S30, abs=1e-12)


# ----------------------------------------------------------------------- seeds and keys


def test_realistic_scenarios_are_deterministic_per_seed():
    text = (
        VIB.format(v=15.0)
        + "broadband_vertical_mps2 = 0.1\n"
        + dedent(
            """
        [odometer]
        slide_depth_mps = 0.5
        wsp_jitter = 0.5
        noise_mps = 0.01
        """
        )
    )
    text = text.replace(
        "initial_speed_mps = 15.0",
        "initial_speed_mps = 15.0\n[[train]]\nduration_s = 8.0\naccel_mps2 = -1.0",
    )
    a, b = sim_of(text), sim_of(text)
    assert a.frames.tobytes() == b.frames.tobytes()
    c = sim_of("seed = 9\n" + text)
    assert c.frames["data"].tobytes() != a.frames["data"].tobytes()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("jerk_mps3 = -1.0", r"jerk_mps3: must be >= 0"),
        ("[vibration]\nfrequency_hz = 150.0", r"vibration\.frequency_hz: must be <= 100"),
        (
            "[vibration]\nbroadband_low_hz = 10.0\nbroadband_high_hz = 5.0",
            r"vibration\.broadband_high_hz: must be > broadband_low_hz",
        ),
        (
            "[odometer]\nlow_adhesion_start_s = 5.0\nlow_adhesion_end_s = 2.0",
            r"odometer\.low_adhesion_end_s: must be > low_adhesion_start_s",
        ),
        ("[vibration]\nvertical = 0.2", r"vibration\.vertical: unknown key"),
    ],
)
def test_new_keys_are_validated(text: str, message: str):
    with pytest.raises(ConfigError, match=message):
        parse_scenario(text, "bad.toml")
