"""Track irregularity fixed in position (issue 25) against hand-computed rings: an axle
passing a feature at p at speed v_p gives the board A (|v_p| / 20)^n exp(-zeta wn tau)
(sin(wd tau) - wd zeta^2 tau) vertically from the instant it is there (the second term
takes back the velocity the ring leaves: the body comes back to rest), so the same
metre rings in every run, whatever the seed or the speed profile, scaled by the speed. A
channel at +-30 deg reads z sin(30 deg), so z = (ch1 - ch3) / (2 sin 30) - g on level
track (the along-track force cancels). Frames are decoded with protocol.can_codec
(tests.helpers.adc_values)."""

from __future__ import annotations

import math
from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate
from devices.errors import ConfigError
from protocol.layout import G0, NOMINAL_SCALE
from tests.helpers import adc_values

RATE = 100
S30 = math.sin(math.radians(30.0))
F, ZETA = 8.0, 0.1  # the ring of these tests
WN = 2 * math.pi * F
WD = WN * math.sqrt(1 - ZETA * ZETA)
FEATURE = """
[[track_irregularity.features]]
position_m = 100.0
amplitude_mps2 = 0.2
frequency_hz = 8.0
damping = 0.1
"""


def run(keys: str, head: str, duration: float = 20.0, seed: int = 1):
    """(t, z) of a level run: z the board's vertical specific force minus g."""
    text = dedent(
        f"""
        duration_s = {duration}
        sample_rate_hz = {RATE}
        seed = {seed}
        """
    )
    text += dedent(head) + dedent(
        """
        [board]
        antialias_filter = false
        [body_pitch]
        enabled = false
        [body_modes]
        enabled = false
        [standstill]
        enabled = false
        [track_irregularity]
        """
    )
    sim = simulate(parse_scenario(text + dedent(keys), "joints.toml"))
    acc = adc_values(sim.frames)
    return sim.truth["time_s"], (acc[:, 0] - acc[:, 2]) / (2 * S30) - G0


def ring(t: np.ndarray, t0: float, amp: float) -> np.ndarray:
    tau = t - t0
    shape = np.sin(WD * tau) - WD * ZETA**2 * tau
    out = amp * np.exp(-ZETA * WN * tau) * shape
    return np.where(tau >= 0.0, out, 0.0)


LSB = 3 * NOMINAL_SCALE  # z from two channels' codes


def test_a_feature_rings_when_the_board_passes_it_scaled_by_speed():
    t, z = run(FEATURE, "initial_speed_mps = 10.0")
    # at 10 m/s from 0 m the board is at 100 m at 10 s: 0.2 x 10/20 = 0.1 m/s^2
    assert np.abs(z - ring(t, 10.0, 0.1)).max() <= LSB
    assert np.abs(z).max() == pytest.approx(0.1 * 0.85, rel=0.05)  # peak e^-0.1 wn t at wd/4


def test_a_ring_leaves_the_body_at_rest_its_acceleration_averages_to_zero():
    # the integral of the ring is the body's vertical velocity after it: 0 (a dip leaves
    # the wheel at its height). A ring of 0.1 sin(wd tau) would leave 0.1 wd / wn^2 =
    # 0.00198 m/s, a steady 0.003 m/s^2 upwards on 25 m rail at 10 m/s (0.4 / s x 4 axles)
    t, z = run(FEATURE, "initial_speed_mps = 10.0")
    dt = 1.0 / RATE
    # sampled: Euler-Maclaurin, sum f(k dt) dt = integral + dt f(0) / 2 - dt^2 f'(0) / 12,
    # f(0) = 0, f'(0) = 0.1 wd (1 - zeta^2): -4.1e-5 m/s
    want = -(dt**2) / 12.0 * 0.1 * WD * (1.0 - ZETA**2)
    assert float(np.sum(z)) * dt == pytest.approx(want, abs=5e-6)
    # yet it is felt: its first half cycle gives the body 0.1 (1 + e^(-zeta wn pi / wd))
    # wd / wn^2 = 0.0034 m/s upwards
    first = (t >= 10.0) & (t < 10.0 + math.pi / WD)
    assert float(np.sum(z[first])) * dt > 2e-3


def test_the_same_metre_rings_again_in_a_run_of_another_seed_and_speed_profile():
    # from standstill at 1 m/s^2: at 100 m at sqrt(200) = 14.142 s, at 14.142 m/s
    head = """
        [[train]]
        duration_s = 20.0
        accel_mps2 = 1.0
    """
    t, z = run(FEATURE, head, seed=7)
    t0 = math.sqrt(200.0)
    assert np.abs(z - ring(t, t0, 0.2 * t0 / 20.0)).max() <= LSB  # 0.1414 m/s^2
    quiet = t < t0
    assert np.abs(z[quiet]).max() <= LSB


def test_speed_exponent():
    t, z = run("speed_exponent = 2.0\n" + FEATURE, "initial_speed_mps = 10.0")
    assert np.abs(z - ring(t, 10.0, 0.2 * 0.25)).max() <= LSB  # (10 / 20)^2


def test_every_axle_rings_where_it_passes():
    keys = "axles_m = [7.1, -7.1]\n" + FEATURE
    t, z = run(keys, "initial_speed_mps = 10.0")
    # the leading axle is 7.1 m ahead: at 100 m when the board is at 92.9 m (9.29 s)
    want = ring(t, 9.29, 0.1) + ring(t, 10.71, 0.1)
    assert np.abs(z - want).max() <= LSB


def joint_amplitudes(t: np.ndarray, z: np.ndarray, onsets: list[float]) -> np.ndarray:
    """Least-squares amplitude of a unit ring at each onset."""
    basis = np.stack([ring(t, t0, 1.0) for t0 in onsets], axis=1)
    amp, *_ = np.linalg.lstsq(basis, z, rcond=None)
    return amp


JOINTS = """
joint_spacing_m = 25.0
joint_start_m = 12.5
joint_amplitude_mps2 = 0.3
joint_spread = 0.5
frequency_hz = 8.0
damping = 0.1
track_seed = {track}
"""


def test_periodic_joints_are_the_lines_own_whatever_the_run():
    # run A: 10 m/s from 0 m, joints at 12.5, 37.5, ..., 187.5 m (8), at (12.5 + 25 k) / 10 s
    ta, za = run(JOINTS.format(track=4), "initial_speed_mps = 10.0", seed=1)
    # run B: 20 m/s from -50 m to 250 m, another seed: joints -37.5 .. 237.5 m (12), at
    # (p + 50) / 20 s; the 8 of run A are its 3rd to 10th
    head = "initial_speed_mps = 20.0\ninitial_position_m = -50.0"
    tb, zb = run(JOINTS.format(track=4), head, duration=15.0, seed=2)
    pos = [12.5 + 25 * k for k in range(8)]
    amp_a = joint_amplitudes(ta, za, [p / 10.0 for p in pos]) / (10.0 / 20.0)
    pos_b = [-37.5 + 25 * k for k in range(12)]
    amp_b = joint_amplitudes(tb, zb, [(p + 50.0) / 20.0 for p in pos_b])[2:10] / (20.0 / 20.0)
    assert amp_a == pytest.approx(amp_b, rel=1e-3, abs=1e-4)  # the same joint, the same hit
    assert np.all((amp_a >= 0.15 - 1e-3) & (amp_a <= 0.45 + 1e-3))  # 0.3 (1 +- 0.5)
    assert np.ptp(amp_a) > 0.01  # joints differ from one another
    tc, zc = run(JOINTS.format(track=5), "initial_speed_mps = 10.0", seed=1)
    amp_c = joint_amplitudes(tc, zc, [p / 10.0 for p in pos]) / 0.5
    assert np.abs(amp_c - amp_a).max() > 0.01  # another line: other joints
    # and nothing else: the rings alone
    want = sum(ring(ta, p / 10.0, a * 0.5) for p, a in zip(pos, amp_a, strict=True))
    assert np.abs(za - want).max() <= 2 * LSB


def test_none_by_default_and_none_at_standstill():
    _, z = run("", "initial_speed_mps = 20.0", duration=5.0)
    assert np.abs(z).max() <= LSB  # no features by default
    _, z = run(FEATURE, "initial_position_m = 100.0", duration=5.0)
    assert np.abs(z).max() <= LSB  # standing on the feature


@pytest.mark.parametrize(
    "keys",
    [
        "[[track_irregularity.features]]\namplitude_mps2 = 0.1\n",  # no position
        "axles_m = []\n",
        "axles_m = [1.0, 'x']\n",
        "joint_spacing_m = 0.5\n",
        "joint_spread = 2.0\n",
        "bogus = 1\n",
    ],
)
def test_bad_keys_are_config_errors(keys: str):
    with pytest.raises(ConfigError):
        run(keys, "", duration=1.0)


def test_the_rings_and_the_body_modes_are_the_same_in_any_chunks():
    from devices.emulator.stream import RunCounts, simulate_chunks

    text = dedent(
        """
        duration_s = 8.0
        sample_rate_hz = 200
        seed = 3
        initial_speed_mps = 15.0
        [track_irregularity]
        axles_m = [7.1, 4.9, -4.9, -7.1]
        joint_spacing_m = 25.0
        [[track_irregularity.features]]
        position_m = 60.0
        """
    )
    sc = parse_scenario(text, "chunks.toml")  # the default body modes on, too
    whole = simulate(sc)
    for chunk_s in (0.37, 3.0):
        chunks = list(simulate_chunks(sc, chunk_s=chunk_s, counts=RunCounts(sc)))
        assert np.concatenate([c.frames for c in chunks]).tobytes() == whole.frames.tobytes()
