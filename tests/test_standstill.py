"""A standing car is never still (issue 25): HVAC hum, doors, boarding. Checked against
formulas computed here from decoded frames (the hum's amplitude by least squares, the door's
decaying ring) and, for the boarding, against compound-Poisson statistics over many seeds."""

from __future__ import annotations

import math
from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate
from devices.emulator.body_pitch import BodyPitch, scenario_stations
from devices.emulator.standstill import plan
from devices.errors import ConfigError
from protocol.layout import G0, NOMINAL_SCALE
from tests.helpers import adc_values

# 60 s standing: one station 0..60 s, doors open at 12 s and close at 48 s
STILL = """
seed = {seed}
duration_s = 60.0
sample_rate_hz = 200
speed_ref = false
[board]
antialias_filter = false
[body_pitch]
load_step_deg = 0.0
[standstill]
hvac_mps2 = {hvac}
hvac_hz = 14.0
door_mps2 = {door}
door_hz = 8.0
door_decay_s = 0.3
boarding_rate_hz = {rate}
boarding_step_deg = 0.002
"""


def scenario(seed=1, hvac=0.0, door=0.0, rate=0.0):
    text = STILL.format(seed=seed, hvac=hvac, door=door, rate=rate)
    return parse_scenario(dedent(text), "still.toml")


def adc(sim) -> np.ndarray:
    return adc_values(sim.frames)


def tone_amplitude(y: np.ndarray, t: np.ndarray, hz: float) -> float:
    w = 2 * math.pi * hz
    basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    coef = np.linalg.lstsq(basis, y, rcond=None)[0]
    return float(math.hypot(coef[0], coef[1]))


def test_the_hvac_hums_at_standstill_normal_to_and_along_the_track():
    sim = simulate(scenario(hvac=0.02))
    acc, t = adc(sim), sim.truth["time_s"]
    # ch2 (0 deg) reads x alone; ch1 - ch3 (+/-30 deg) = 2 sin 30 (g + z) = g + z
    assert tone_amplitude(acc[:, 1], t, 14.0) == pytest.approx(0.01, abs=3 * NOMINAL_SCALE)
    z = acc[:, 0] - acc[:, 2] - G0
    assert tone_amplitude(z, t, 14.0) == pytest.approx(0.02, abs=3 * NOMINAL_SCALE)
    assert np.std(acc[:, 1]) > 0.005  # not exactly zero at rest (no white noise configured)


def test_the_anti_alias_filter_passes_the_hum_at_its_sinc3_gain():
    # a 50 Hz board: |sin(pi f / fs) / (M sin(pi f / (M fs)))|^3 at 14 Hz, M = 64
    m, fs, f = 64, 50.0, 14.0
    gain = abs(math.sin(math.pi * f / fs) / (m * math.sin(math.pi * f / (m * fs)))) ** 3
    assert gain == pytest.approx(0.6721, abs=1e-4)  # sin(0.88) / 0.880 = 0.876, cubed
    text = STILL.format(seed=2, hvac=0.5, door=0.0, rate=0.0)
    text = text.replace("sample_rate_hz = 200", "sample_rate_hz = 50")
    sim = simulate(parse_scenario(dedent(text.replace("antialias_filter = false", "")), "f.toml"))
    acc, t = adc(sim), sim.truth["time_s"]
    assert tone_amplitude(acc[:, 1], t, f) == pytest.approx(0.25 * gain, abs=3 * NOMINAL_SCALE)
    z = acc[:, 0] - acc[:, 2] - G0
    assert tone_amplitude(z, t, f) == pytest.approx(0.5 * gain, abs=3 * NOMINAL_SCALE)


def test_a_door_rings_the_body_with_the_configured_decay():
    sim = simulate(scenario(door=0.1))
    x, t = adc(sim)[:, 1], sim.truth["time_s"]  # ch2: along the track
    assert np.all(x[t < 12.0] == 0.0)  # quiet until the doors open at 20 % of 60 s
    for opened in (12.0, 48.0):
        ring = (t >= opened) & (t < opened + 2.0)
        tau = t[ring] - opened
        want = 0.1 * np.exp(-tau / 0.3) * np.abs(np.sin(2 * math.pi * 8.0 * tau))
        assert np.max(np.abs(np.abs(x[ring]) - want)) <= NOMINAL_SCALE
    # one period (0.125 s) later the ring is e^(-0.125 / 0.3) = 0.659 as strong
    k = int(np.argmin(np.abs(t - (12.0 + 1 / 32))))  # the first crest
    k2 = int(np.argmin(np.abs(t - (12.0 + 1 / 32 + 0.125))))
    assert x[k2] / x[k] == pytest.approx(math.exp(-0.125 / 0.3), rel=1e-3)


def test_boarding_passengers_sway_the_body_by_compound_poisson_steps():
    # 0.5 passengers/s over the 36 s the doors are open: N ~ Poisson(18); each a pitch step
    # N(0, 0.002^2), so the load's pitch after the doors close has variance 18 * 0.002^2
    # (compound Poisson). 400 seeds: the sample variance within +/-25 % (its relative
    # standard error here is sqrt((2 + 3/18) / 400) = 7 %: over 3 sigma)
    end = []
    counts = []
    for seed in range(400):
        sc = scenario(seed=seed, rate=0.5)
        stations = scenario_stations(sc)
        assert stations == [(0.0, 60.0)]
        p = plan(sc, stations)
        counts.append(len(p.board_t))
        end.append(BodyPitch(sc, stations, (p.board_t, p.board_deg)).deg(np.array([59.0]))[0])
    assert np.mean(counts) == pytest.approx(18.0, abs=4 * math.sqrt(18 / 400))
    assert np.var(end) == pytest.approx(18 * 0.002**2, rel=0.25)
    # one passenger alone (a quiet station): the body sways to the step with the
    # suspension's overshoot exp(-pi zeta / sqrt(1 - zeta^2)) = 44 % at pi / wd
    for seed in range(100):
        sc = scenario(seed=seed, rate=0.03)
        st = scenario_stations(sc)
        p = plan(sc, st)
        if len(p.board_t) == 1:
            break
    body = BodyPitch(sc, st, (p.board_t, p.board_deg))
    peak = float(p.board_t[0]) + 1 / (2 * 1.2 * math.sqrt(1 - 0.25**2))
    overshoot = math.exp(-math.pi * 0.25 / math.sqrt(1 - 0.25**2))
    assert body.deg(np.array([peak]))[0] == pytest.approx(p.board_deg[0] * (1 + overshoot))
    assert body.deg(np.array([59.0]))[0] == pytest.approx(p.board_deg[0])


def test_keys_are_checked_and_it_can_be_switched_off():
    sc = parse_scenario("", "d.toml")
    assert sc.standstill.enabled and sc.standstill.hvac_mps2 == 0.01
    with pytest.raises(ConfigError, match=r"standstill\.hvac_hz"):
        parse_scenario("sample_rate_hz = 50\n[standstill]\nhvac_hz = 30.0\n", "d.toml")
    off = simulate(
        parse_scenario(
            "duration_s = 20.0\n[standstill]\nenabled = false\n[body_pitch]\nenabled = false\n",
            "o.toml",
        )
    )
    acc = adc(off)
    assert np.all(acc == acc[0])  # no noise, no pitch change at rest: exactly still
