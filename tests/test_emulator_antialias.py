"""The board's anti-alias filter and decimation (issue 25) against gains computed by hand.

The ADC's decimator is a sinc^3 of 64x oversampling: |H(f)| = |sin(pi f/fs) /
(64 sin(pi f/(64 fs)))|^3 (docs/EMULATOR.md). The frames are decoded with protocol.can_codec
and each tone's amplitude and phase are fitted by least squares; nothing here calls the
emulator's model.

Hand values (fs = 50 Hz):
* 40 Hz: x = 0.8 pi = 2.513274, sin x = 0.587785, 64 sin(x/64) = 2.512628,
  ratio 0.233932, cubed 0.012802 (the unfiltered board would alias it to 10 Hz at full size);
* 2 Hz: x = 0.04 pi = 0.125664, sin x = 0.125333, 64 sin(x/64) = 0.125664,
  ratio 0.997371, cubed 0.992133;
* 20 Hz: x = 0.4 pi = 1.256637, sin x = 0.951057, 64 sin(x/64) = 1.256556,
  ratio 0.756875, cubed 0.433584 (19.9 Hz: 0.437436, 19.95 Hz: 0.435509).
"""

from __future__ import annotations

import math
from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate
from devices.emulator.stream import RunCounts, simulate_chunks
from protocol.layout import G0, NOMINAL_SCALE
from tests.helpers import adc_values

RATE = 50
S30 = math.sin(math.radians(30.0))

MOUNT = """
seed = 5
duration_s = 20.0
sample_rate_hz = 50
body_modes.enabled = false  # the mounting's tone alone (issue 25)
[body_pitch]
enabled = false  # a load step at the station would shift the fitted tone
[standstill]
enabled = false  # so would the HVAC hum and the doors
[[channels]]
angle_deg = 30.0
[[channels]]
angle_deg = 0.0
vibration_mps2 = 1.0
vibration_hz = {f}
vibration_phase_deg = 30.0
[[channels]]
angle_deg = -30.0
[board]
antialias_filter = {on}
"""


def adc(text: str) -> np.ndarray:
    """(n, 3) accelerations from the ADC frames at the nominal scale (fault-free: sample
    order, ch1, ch2, ch3)."""
    sim = simulate(parse_scenario(dedent(text), "antialias.toml"))
    return adc_values(sim.frames)


def tone(y: np.ndarray, f: float) -> tuple[float, float]:
    """(amplitude, phase deg) of a sine at f Hz in samples at RATE, by least squares
    (with a constant)."""
    t = np.arange(len(y)) / RATE
    basis = np.column_stack(
        [np.sin(2 * math.pi * f * t), np.cos(2 * math.pi * f * t), np.ones_like(t)]
    )
    (s, c, _), *_ = np.linalg.lstsq(basis, y, rcond=None)
    return math.hypot(s, c), math.degrees(math.atan2(c, s))


@pytest.mark.parametrize(("f", "gain"), [(40.0, 0.012802), (2.0, 0.992133)])
def test_a_tone_is_kept_at_the_filter_gain_with_its_phase(f: float, gain: float) -> None:
    amp, phase = tone(adc(MOUNT.format(f=f, on="true"))[:, 1], f)
    assert amp == pytest.approx(gain, abs=2e-6)  # a 1 m/s^2 tone; 1 LSB = 2.3e-6
    assert phase == pytest.approx(30.0, abs=0.05)  # linear phase, centred stamp: no delay


def test_without_the_filter_40_hz_aliases_to_10_hz_at_full_size() -> None:
    y = adc(MOUNT.format(f=40.0, on="false"))[:, 1]
    assert tone(y, 40.0)[0] == pytest.approx(1.0, abs=2e-6)
    # sampled at 50 Hz, sin(2 pi 40 n/50 + p) = -sin(2 pi 10 n/50 - p): the same samples
    amp, phase = tone(y, 10.0)
    assert amp == pytest.approx(1.0, abs=2e-6)
    assert phase == pytest.approx(180.0 - 30.0, abs=0.05)


BODY = """
seed = 6
duration_s = 20.0
sample_rate_hz = 50
initial_speed_mps = 20.0
body_modes.enabled = false  # the body's tone and band alone (issue 25)
[vibration]
vertical_mps2 = {tone}
frequency_hz = 20.0
broadband_vertical_mps2 = {band}
broadband_low_hz = 19.9
broadband_high_hz = 20.0
reference_speed_mps = 20.0
[board]
antialias_filter = {on}
"""


def body_z(tone_mps2: float, band_mps2: float, on: str) -> np.ndarray:
    """The body's vertical acceleration from ch1 - ch3 (nominal +-30 deg), gravity off."""
    acc = adc(BODY.format(tone=tone_mps2, band=band_mps2, on=on))
    z: np.ndarray = (acc[:, 0] - acc[:, 2]) / (2 * S30) - G0
    return z


def test_the_body_tone_passes_at_the_filter_gain() -> None:
    assert tone(body_z(0.5, 0.0, "true"), 20.0)[0] == pytest.approx(0.5 * 0.433584, abs=1e-5)
    assert tone(body_z(0.5, 0.0, "false"), 20.0)[0] == pytest.approx(0.5, abs=1e-5)


def test_each_broadband_tone_passes_at_its_own_gain() -> None:
    """64 tones in 19.9..20 Hz, gains 0.437436..0.433584: the filtered run is the
    unfiltered one (same seed, same tones) times H(19.95 Hz) = 0.435509 to within
    64 tones x a = 0.3 sqrt(2/64) x 0.001927 (the gain's spread from the centre)."""
    on, off = body_z(0.0, 0.3, "true"), body_z(0.0, 0.3, "false")
    bound = 64 * 0.3 * math.sqrt(2 / 64) * 0.001927 + 4 * NOMINAL_SCALE
    assert np.abs(on - 0.435509 * off).max() <= bound
    assert np.abs(off).max() > 0.2  # the band is there (RMS 0.3)


def test_the_chunked_run_is_the_whole_run_with_the_filter() -> None:
    """Tones below and above Nyquist, a broadband band and noise, in chunks that cut
    anywhere: the same frames and truth bit for bit as the whole run."""
    text = dedent(BODY.format(tone=0.4, band=0.2, on="true")).replace(
        "broadband_low_hz = 19.9", "broadband_low_hz = 0.5"
    ) + dedent(
        """
        [[channels]]
        angle_deg = 30.0
        noise_mps2 = 0.01
        vibration_mps2 = 0.3
        vibration_hz = 61.0
        [[channels]]
        angle_deg = 0.0
        vibration_mps2 = 1.0
        vibration_hz = 40.0
        [[channels]]
        angle_deg = -30.0
        noise_mps2 = 0.01
        """
    )
    sc = parse_scenario(text, "antialias.toml")
    assert sc.board.antialias_filter
    whole = simulate(sc)
    for chunk_s in (0.37, 3.0):
        chunks = list(simulate_chunks(sc, chunk_s=chunk_s, counts=RunCounts(sc)))
        frames = np.concatenate([c.frames for c in chunks])
        truth = np.concatenate([c.truth for c in chunks])
        assert frames.tobytes() == whole.frames.tobytes(), chunk_s
        assert truth.tobytes() == whole.truth.tobytes(), chunk_s
