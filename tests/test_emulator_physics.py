"""The virtual board against ICD physics, computed here by hand (math module, per sample).

Nothing in this file calls the emulator's own model (devices.emulator.world): truth,
codes, speeds and timestamps are recomputed from the scenario with plain formulas.
"""

from __future__ import annotations

import math
from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate
from protocol.layout import CODE_MAX, NOMINAL_SCALE, STATUS_OVR
from protocol.records import AdcSample, BoardStatus, SpeedRef
from tests.helpers import records

G = 9.81  # deliberately not G0: the world's gravity must come from the scenario

SCENARIO = f"""
seed = 3
duration_s = 50.0
sample_rate_hz = 100
g = {G}
speed_ref = true
vertical_curve_m = 40.0
body_modes.enabled = false  # nor has it modes of its own (issue 25)
[body_pitch]
enabled = false  # the hand formula below is the ICD's, of a body that does not pitch
[standstill]
enabled = false  # nor hum

[[track]]
length_m = 100.0
gradient_permil = 0.0
[[track]]
length_m = 200.0
gradient_permil = 20.0
[[track]]
length_m = 1000.0
gradient_permil = -10.0
vertical_curve_m = 0.0

[[train]]
duration_s = 20.0
accel_mps2 = 0.5
[[train]]
duration_s = 16.0
[[train]]
duration_s = 14.0
accel_mps2 = -1.0

[[channels]]
angle_deg = 30.4
bias_mps2 = 0.003
scale_error = 0.001
[[channels]]
angle_deg = -0.3
vibration_mps2 = 0.05
vibration_hz = 7.0
vibration_phase_deg = 30.0
[[channels]]
angle_deg = -29.5
scale_error = -0.002

[odometer]
time0_ticks = 100
drift_ppm = 500.0
offset_s = 0.005

[board]
antialias_filter = false  # the formula below has the unfiltered 7 Hz tone (issue 25)
"""


def hand_motion(t: float) -> tuple[float, float, float]:
    """(accel, speed, position) of the scenario's train: 0.5 m/s^2 for 20 s, cruise 16 s,
    brake at 1 m/s^2, which stops it after 10 s (braking rule), then 4 s at rest."""
    if t < 20.0:
        return 0.5, 0.5 * t, 0.25 * t * t
    if t < 36.0:
        return 0.0, 10.0, 100.0 + 10.0 * (t - 20.0)
    if t < 46.0:
        tau = t - 36.0
        return -1.0, 10.0 - tau, 260.0 + 10.0 * tau - 0.5 * tau * tau
    return 0.0, 0.0, 310.0


def hand_curve_accel(x: float, v: float) -> float:
    """v^2/R normal to the track: 1/R = d(alpha)/dx = (G' / 1000) / (1 + (G / 1000)^2) on the
    40 m curve (G' = 20 permil / 40 m); the abrupt change at 300 m has no curve."""
    if not 80.0 < x < 120.0:
        return 0.0
    return v * v * (0.020 / 40.0) / (1.0 + (hand_gradient(x) / 1000.0) ** 2)


def hand_gradient(x: float) -> float:
    """0 until 100 m, 20 from 100 m, -10 from 300 m; the 0 -> 20 change spread linearly over
    40 m centred on 100 m, the 20 -> -10 change abrupt (vertical_curve_m = 0)."""
    if x < 80.0:
        return 0.0
    if x < 120.0:
        return 20.0 * (x - 80.0) / 40.0
    if x < 300.0:
        return 20.0
    return -10.0


@pytest.fixture(scope="module")
def sim():
    return simulate(parse_scenario(dedent(SCENARIO), "physics.toml"))


_decoded: dict[int, list] = {}


def decoded(sim):
    """Every frame decoded with protocol.can_codec (once per simulation)."""
    if id(sim) not in _decoded:
        _decoded[id(sim)] = records(sim.frames)
    return _decoded[id(sim)]


def test_truth_follows_hand_kinematics_and_track(sim):
    tr = sim.truth
    assert len(tr) == 5000
    for k in range(0, 5000):
        t = k / 100
        a, v, x = hand_motion(t)
        assert tr["time_s"][k] == t
        assert tr["counter"][k] == k
        assert tr["accel_mps2"][k] == pytest.approx(a, abs=1e-12)
        assert tr["speed_mps"][k] == pytest.approx(v, abs=1e-9)
        assert tr["position_m"][k] == pytest.approx(x, abs=1e-9)
        assert tr["gradient_permil"][k] == pytest.approx(hand_gradient(x), abs=1e-9)
    # the profile really was exercised: on the curve, on 20, and at rest
    grads = set(np.round(tr["gradient_permil"], 6).tolist())
    assert {0.0, 20.0, -10.0} <= grads and any(0 < g < 20 for g in grads)
    assert tr["speed_mps"][-1] == 0.0 and tr["accel_mps2"][-1] == 0.0


def test_codes_agree_with_icd_formula_within_one_lsb(sim):
    sc = sim.scenario
    ch_models = sc.channels
    adc = [r for r in decoded(sim) if isinstance(r, AdcSample)]
    assert len(adc) == 3 * 5000
    worst = 0
    for i, r in enumerate(adc):
        k = i // 3
        assert r.channel == i % 3 + 1, "ch1, ch2, ch3 back to back"
        assert r.counter == k % 256
        t = k / 100
        a, v, x = hand_motion(t)
        alpha = math.atan(hand_gradient(x) / 1000.0)
        m = ch_models[r.channel - 1]
        theta = math.radians(m.angle_deg)
        value = a * math.cos(theta) + G * math.sin(alpha + theta)
        value += hand_curve_accel(x, v) * math.sin(theta)  # normal to the track
        value = value * (1.0 + m.scale_error) + m.bias_mps2
        value += m.vibration_mps2 * math.sin(
            2 * math.pi * m.vibration_hz * t + math.radians(m.vibration_phase_deg)
        )
        expected = round(value / NOMINAL_SCALE)
        worst = max(worst, abs(r.code - expected))
        assert r.status == 0
        assert r.timestamp == (k * 100) % 65536  # 100 Hz -> 100 ticks of 100 us
    assert worst <= 1


def test_send_times_are_whole_microseconds_and_frames_back_to_back(sim):
    t = sim.frames["t"]
    us = np.rint(t * 1e6)
    assert np.array_equal(us / 1e6, t), "t is an integer number of microseconds / 1e6"
    assert np.all(np.diff(t) > 0)
    ids = sim.frames["id"]
    ch1 = np.flatnonzero(ids == 0x101)
    ch1 = ch1[ch1 + 2 < len(ids)]
    assert np.all(ids[ch1 + 1] == 0x102) and np.all(ids[ch1 + 2] == 0x103)
    gap = np.rint((t[ch1 + 1] - t[ch1]) * 1e6)
    assert np.all(gap == 250)  # 8-byte CAN frame at 500 kbit/s, nothing in between
    # each triple is sent within a millisecond of its sampling instant
    assert np.all(t[ch1] - np.arange(len(ch1)) / 100 < 1e-3)


def test_board_status_at_10_hz(sim):
    st = [
        (f["t"], r)
        for f, r in zip(sim.frames, decoded(sim), strict=True)
        if isinstance(r, BoardStatus)
    ]
    assert len(st) == 500
    times = np.array([t for t, _ in st])
    assert np.allclose(np.diff(times), 0.1, atol=1e-3)
    for k, (_, r) in enumerate(st):
        assert (r.counter, r.state, r.sample_rate, r.temperature, r.supply, r.errors) == (
            k % 256,
            1,
            100,
            35,
            240,
            0,
        )


def test_speed_ref_from_true_speed_on_the_odometer_clock(sim):
    sp = [
        (f["t"], r)
        for f, r in zip(sim.frames, decoded(sim), strict=True)
        if isinstance(r, SpeedRef)
    ]
    drift = 1 + 500e-6
    expected_n = math.floor((50.0 * drift - 0.005) / 0.02) + 1
    assert len(sp) == expected_n
    for m, (t, r) in enumerate(sp):
        t_meas = (0.005 + 0.02 * m) / drift
        # sent when measured, or after the frame already on the bus (at most an ADC triple)
        assert t_meas - 1e-6 <= t <= t_meas + 1e-3
        assert r.counter == m % 256
        assert r.timestamp == (100 + 50 + 200 * m) % 65536  # own start + offset + 20 ms steps
        assert abs(r.speed - round(hand_motion(t_meas)[1] * 1000)) <= 1


def test_over_range_clips_with_ovr():
    sc = parse_scenario(
        dedent(
            """
            duration_s = 1.0
            speed_ref = false
            [standstill]
            enabled = false
            [[channels]]
            bias_mps2 = 15.0
            [[channels]]
            bias_mps2 = -20.0
            [[channels]]
            """
        ),
        "ovr.toml",
    )
    recs = records(simulate(sc).frames)
    adc = [r for r in recs if isinstance(r, AdcSample)]
    ch1 = {(r.code, r.status) for r in adc if r.channel == 1}
    ch2 = {(r.code, r.status) for r in adc if r.channel == 2}
    ch3 = {(r.code, r.status) for r in adc if r.channel == 3}
    # 9.80665 * sin(30 deg) + 15 = 19.9 m/s^2 > 2 g: clipped at the top rail
    assert ch1 == {(CODE_MAX, STATUS_OVR)}
    assert ch2 == {(-CODE_MAX - 1, STATUS_OVR)}
    assert ch3 == {(round(9.80665 * math.sin(math.radians(-30)) / NOMINAL_SCALE), 0)}


def test_white_noise_has_the_configured_deviation():
    sc = parse_scenario(
        "duration_s = 50.0\nspeed_ref = false\nbody_modes.enabled = false\n"
        "[body_pitch]\nenabled = false\n"
        "[standstill]\nenabled = false\n"
        "[[channels]]\nnoise_mps2 = 0.01\n"
        "[[channels]]\n[[channels]]\nnoise_mps2 = 0.002\n",
        "noise.toml",
    )
    recs = records(simulate(sc).frames)
    recs = [r for r in recs if isinstance(r, AdcSample)]
    by_ch = {
        c: np.array([r.code for r in recs if r.channel == c]) * NOMINAL_SCALE for c in (1, 2, 3)
    }
    assert np.std(by_ch[1]) == pytest.approx(0.01, rel=0.05)
    assert np.std(by_ch[2]) == 0.0
    assert np.std(by_ch[3]) == pytest.approx(0.002, rel=0.05)
    assert np.mean(by_ch[1]) == pytest.approx(9.80665 * 0.5, abs=0.001)


def test_reversing_only_where_allowed():
    sc = parse_scenario(
        dedent(
            """
            duration_s = 30.0
            initial_speed_mps = 2.0
            [[train]]
            duration_s = 10.0
            accel_mps2 = -1.0
            [[train]]
            duration_s = 5.0
            accel_mps2 = -1.0
            allow_reverse = true
            [[train]]
            duration_s = 10.0
            accel_mps2 = 1.0
            """
        ),
        "rev.toml",
    )
    tr = simulate(sc).truth
    at = {
        round(t, 3): (a, v)
        for t, a, v in zip(tr["time_s"], tr["accel_mps2"], tr["speed_mps"], strict=True)
    }
    assert at[1.0] == (-1.0, 1.0)
    assert at[5.0] == (0.0, 0.0)  # stopped at 2 s and stays: no reversing without allow_reverse
    assert at[12.0] == (-1.0, -2.0)  # backwards now
    assert at[17.0][1] == pytest.approx(-3.0)  # braking the backwards run (a > 0)...
    assert at[24.0] == (0.0, 0.0)  # ...stops at 0 and does not turn forwards
