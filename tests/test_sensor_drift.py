"""Sensor bias random walk and per-channel temperature (issue 25), against statistics and
first-order responses computed here: the walk's variance q^2 T after T seconds (over many
seeds) and of its increments (within one run), its zero start; each channel's temperature
behind the board's (two first-order lags in series, and an Euler integration of the two
equations as an independent check); the board cooling at a station and warming when the
train leaves, as BOARD_STATUS reports it."""

from __future__ import annotations

import math
from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate
from devices.emulator.body_pitch import scenario_stations
from devices.emulator.stream import RunCounts, simulate_chunks
from devices.errors import ConfigError
from protocol.layout import NOMINAL_SCALE
from protocol.records import BoardStatus
from tests.helpers import adc_values, records

# level, no hum, no pitch, no body modes: ch2 (0 deg) reads its own bias drift alone
QUIET = """
seed = {seed}
duration_s = {duration}
sample_rate_hz = 50
speed_ref = false
[standstill]
enabled = false
[body_pitch]
enabled = false
[body_modes]
enabled = false
"""


def adc(sim) -> np.ndarray:
    return adc_values(sim.frames)


def status_temperatures(sim) -> tuple[np.ndarray, np.ndarray]:
    t, temp = [], []
    for f, rec in zip(sim.frames, records(sim.frames), strict=True):
        if isinstance(rec, BoardStatus):
            t.append(float(f["t"]))
            temp.append(rec.temperature)
    return np.array(t), np.array(temp)


WALK = (
    QUIET
    + """
[[channels]]
bias_walk_mps2_per_sqrt_s = {q1}
[[channels]]
bias_walk_mps2_per_sqrt_s = {q2}
[[channels]]
"""
)


def walk_run(seed: int, duration: float, q1: float = 0.0, q2: float = 1e-3):
    text = WALK.format(seed=seed, duration=duration, q1=q1, q2=q2)
    return simulate(parse_scenario(dedent(text), "walk.toml"))


def test_the_bias_walk_has_variance_q2_t_after_t_seconds():
    # q = 1e-3 m/s^2/sqrt(s): after 4 s the bias has spread to sigma 2e-3, after 10 s to
    # 3.16e-3 (1 350 LSB); 400 seeds: the sample variance within +/-25 % (relative standard
    # error sqrt(2 / 400) = 7 %: 3.5 sigma), the mean within 4 standard errors
    q = 1e-3
    at4, at10, first = [], [], []
    for seed in range(400):
        x = adc(walk_run(seed, 10.0, q2=q))[:, 1]  # 500 samples, t = n / 50
        first.append(x[0])
        at4.append(x[200])
        at10.append(x[499])
    at4, at10 = np.array(at4), np.array(at10)
    assert np.all(np.array(first) == 0.0)  # the sheet is right at the start
    assert np.var(at4) == pytest.approx(q * q * 4.0, rel=0.25)
    assert np.var(at10) == pytest.approx(q * q * 9.98, rel=0.25)
    assert abs(np.mean(at10)) < 4 * q * math.sqrt(9.98 / 400)
    # independent increments: the walk after 4 s says nothing of its next 6 s
    r = np.corrcoef(at4, at10 - at4)[0, 1]
    assert abs(r) < 4 / math.sqrt(400)


def test_the_walk_s_increments_within_one_run_and_its_channels_are_independent():
    # one 2 000 s run: 2 000 increments over 1 s, each N(0, q^2 * 1 s): their variance within
    # +/-12 % (relative standard error sqrt(2 / 2000) = 3.2 %); 200 over 10 s: q^2 * 10 s
    q1, q2 = 2e-4, 1e-3
    acc = adc(walk_run(7, 2000.0, q1=q1, q2=q2))
    for ch, q in ((0, q1), (1, q2)):
        x = acc[:, ch] - acc[0, ch]
        d1 = np.diff(x[::50])
        d10 = np.diff(x[::500])
        assert np.var(d1) == pytest.approx(q * q, rel=0.12), ch
        assert np.var(d10) == pytest.approx(q * q * 10.0, rel=0.35), ch
    d_a = np.diff(acc[::50, 0])
    d_b = np.diff(acc[::50, 1])
    assert abs(np.corrcoef(d_a, d_b)[0, 1]) < 4 / math.sqrt(2000)
    assert np.all(acc[:, 2] == acc[0, 2])  # no walk configured: exactly still


def test_the_walk_is_the_same_in_chunks_as_in_one_run():
    sc = parse_scenario(dedent(WALK.format(seed=3, duration=30.0, q1=1e-4, q2=1e-3)), "w.toml")
    sim = simulate(sc)
    chunks = list(simulate_chunks(sc, chunk_s=0.37, counts=RunCounts(sc)))
    assert np.concatenate([c.frames for c in chunks]).tobytes() == sim.frames.tobytes()


# -------------------------------------------------------------------- temperatures
WARM = (
    QUIET
    + """
[board]
temperature_c = 15
temperature_end_c = 45.0
temperature_tau_s = 600.0
[[channels]]
bias_tempco_mps2_per_k = 0.001
[[channels]]
bias_tempco_mps2_per_k = 0.001
thermal_lag_s = 300.0
[[channels]]
angle_deg = -30.0
bias_tempco_mps2_per_k = 0.001
thermal_lag_s = 600.0
"""
)


def euler(t_end: float, tau_b: float, tau_c: float, t0: float, u: float, dt: float = 0.01):
    """The two equations integrated step by step: dT_b = (u - T_b) / tau_b dt, then the
    channel dT_c = (T_b - T_c) / tau_c dt (the independent check of the closed form)."""
    tb = tc = t0
    for _ in range(round(t_end / dt)):
        tb, tc = tb + (u - tb) / tau_b * dt, tc + (tb - tc) / tau_c * dt
    return tb, tc


def test_each_channel_lags_the_warming_board_by_its_own_time_constant():
    sim = simulate(parse_scenario(dedent(WARM.format(seed=1, duration=1200.0)), "warm.toml"))
    acc = adc(sim)
    g_s30 = 9.80665 * math.sin(math.radians(30.0))
    at = {600.0: 600 * 50, 1200.0: 1200 * 50 - 1}
    # by hand at 600 s (15 -> 45 degC, tau_b 600 s): the board 45 - 30 e^-1 = 33.964;
    # ch2 (tau 300 s) 15 + 30 (1 - (600 e^-1 - 300 e^-2) / 300) = 15 + 30 * 0.3996 = 26.988;
    # ch3 (tau = tau_b) 15 + 30 (1 - 2 e^-1) = 22.927
    board = 45.0 - 30.0 * math.exp(-1.0)
    ch2 = 15.0 + 30.0 * (1.0 - (600.0 * math.exp(-1.0) - 300.0 * math.exp(-2.0)) / 300.0)
    ch3 = 15.0 + 30.0 * (1.0 - 2.0 * math.exp(-1.0))
    assert (board, ch2, ch3) == pytest.approx((33.964, 26.988, 22.927), abs=1e-3)
    k = at[600.0]
    tol = 2 * NOMINAL_SCALE
    assert acc[k, 0] - g_s30 == pytest.approx(0.001 * (board - 15.0), abs=tol)
    assert acc[k, 1] == pytest.approx(0.001 * (ch2 - 15.0), abs=tol)
    assert acc[k, 2] + g_s30 == pytest.approx(0.001 * (ch3 - 15.0), abs=tol)
    # the Euler integration agrees at the end of the run (to its own 1e-3 K step error)
    k = at[1200.0]
    t_end = k / 50.0
    b_e, c2_e = euler(t_end, 600.0, 300.0, 15.0, 45.0)
    _, c3_e = euler(t_end, 600.0, 600.0, 15.0, 45.0)
    assert acc[k, 0] - g_s30 == pytest.approx(0.001 * (b_e - 15.0), abs=2e-6 + tol)
    assert acc[k, 1] == pytest.approx(0.001 * (c2_e - 15.0), abs=2e-6 + tol)
    assert acc[k, 2] + g_s30 == pytest.approx(0.001 * (c3_e - 15.0), abs=2e-6 + tol)
    # BOARD_STATUS reports the board's (the enclosure's) temperature, not a channel's
    t, temp = status_temperatures(sim)
    j = int(np.argmin(np.abs(t - 600.0)))
    assert temp[j] == round(45.0 - 30.0 * math.exp(-t[j] / 600.0))


STATION = (
    QUIET.replace("speed_ref = false", "speed_ref = false\ninitial_speed_mps = 10.0")
    + """
[board]
temperature_c = 20
temperature_tau_s = 100.0
station_cooling_k = 5.0
[[channels]]
[[channels]]
bias_tempco_mps2_per_k = 0.001
[[channels]]
[[train]]
duration_s = 100.0
[[train]]
duration_s = 10.0
accel_mps2 = -1.0
[[train]]
duration_s = 100.0
[[train]]
duration_s = 10.0
accel_mps2 = 1.0
"""
)
# cruises 0..100 s, brakes to rest at 110 s, stands 110..210 s (a station), departs


def test_the_board_cools_at_a_station_and_warms_again_running():
    sc = parse_scenario(dedent(STATION.format(seed=1, duration=320.0)), "st.toml")
    assert scenario_stations(sc) == [(110.0, 210.0)]
    sim = simulate(sc)
    acc = adc(sim)
    # target 20 degC running, 15 at the station; tau 100 s: 20 - 5 (1 - e^-1) = 16.839 as
    # the train leaves at 210 s, then back towards 20: 20 - 3.161 e^-1 = 18.837 at 310 s
    leave = 20.0 - 5.0 * (1.0 - math.exp(-1.0))
    back = 20.0 - (20.0 - leave) * math.exp(-1.0)
    assert (leave, back) == pytest.approx((16.839, 18.837), abs=1e-3)
    x = acc[:, 1]  # level channel: accel (0 cruising and standing) + 1e-3 (T - 20)
    assert x[50 * 50] == 0.0  # running at 50 s: at 20 degC
    standing = 20.0 - 5.0 * (1.0 - math.exp(-(209.98 - 110.0) / 100.0))
    assert x[10499] == pytest.approx(0.001 * (standing - 20.0), abs=NOMINAL_SCALE)  # 209.98 s
    assert x[310 * 50] == pytest.approx(0.001 * (back - 20.0), abs=NOMINAL_SCALE)
    t, temp = status_temperatures(sim)
    assert set(temp[t < 110.0]) == {20}
    j = int(np.argmin(np.abs(t - 209.0)))
    assert temp[j] == 17  # 16.86 at 209 s
    assert temp[-1] == round(20.0 - (20.0 - leave) * math.exp(-(t[-1] - 210.0) / 100.0))


def test_keys_are_checked_and_default_to_a_perfect_sensor():
    sc = parse_scenario("", "d.toml")
    assert all(c.bias_walk_mps2_per_sqrt_s == 0.0 and c.thermal_lag_s == 0.0 for c in sc.channels)
    assert sc.board.station_cooling_k == 0.0
    with pytest.raises(ConfigError, match=r"channels\[2\]\.bias_walk_mps2_per_sqrt_s"):
        parse_scenario(
            "[[channels]]\n[[channels]]\nbias_walk_mps2_per_sqrt_s = -1.0\n[[channels]]\n", "d"
        )
    with pytest.raises(ConfigError, match=r"board\.station_cooling_k"):
        parse_scenario("[board]\nstation_cooling_k = 500.0\n", "d.toml")
