"""Car-body vibration: one rigid-body motion of the car, felt by all three sensors alike.

The body moves along the track (x) and normal to it (z); each sensor reads that motion
projected on its own axis (x cos(theta) + z sin(theta), devices.emulator.world), so the three
channels agree with each other the way a real car's do. Each axis carries a tone (the body's
bounce/pitch mode, ``frequency_hz``) and a broadband part (track irregularity): a
random-phase multisine of :data:`TONES` tones spread evenly, with jitter, over
[``broadband_low_hz``, ``broadband_high_hz``], scaled to the configured RMS. Everything grows
with speed as (|v| / reference)^exponent and is exactly zero at standstill.

A multisine is a pure function of time: any block of samples can be computed on its own
(here in blocks of :data:`BLOCK` samples, so memory stays small at 1 kHz for an hour), and
the same seed gives the same vibration bit for bit.

The board's anti-alias filter (devices.emulator.antialias) scales each tone by its gain at
the tone's frequency when ``rate_hz`` is given.
"""

from __future__ import annotations

import math

import numpy as np

from devices.emulator.antialias import gain, gain_of
from devices.emulator.scenario import VibrationModel

TONES = 64
"""Tones of the broadband multisine per axis."""

BLOCK = 8192
"""Samples per block when evaluating the multisine."""


def speed_factor(model: VibrationModel, speed_mps: np.ndarray) -> np.ndarray:
    """(|v| / reference)^exponent, exactly 0 at standstill."""
    r = np.abs(np.asarray(speed_mps, dtype=np.float64)) / model.reference_speed_mps
    return np.where(r > 0.0, r**model.speed_exponent, 0.0)


def multisine(
    t: np.ndarray,
    low_hz: float,
    high_hz: float,
    rms: float,
    rng: np.random.Generator,
    rate_hz: float | None = None,
) -> np.ndarray:
    """Broadband noise of the given RMS over [low_hz, high_hz]: TONES sines of equal
    amplitude, one at a random frequency in each of TONES equal sub-bands, random phases;
    each tone times the anti-alias filter's gain of a board at ``rate_hz`` (None: none)."""
    t = np.asarray(t, dtype=np.float64)
    width = (high_hz - low_hz) / TONES
    freq = low_hz + (np.arange(TONES) + rng.random(TONES)) * width
    phase = 2.0 * math.pi * rng.random(TONES)
    amp = rms * math.sqrt(2.0 / TONES)
    omega = 2.0 * math.pi * freq
    out = np.empty_like(t)
    amps = None if rate_hz is None else amp * gain(freq, rate_hz)
    for lo in range(0, len(t), BLOCK):
        block = t[lo : lo + BLOCK]
        tones = np.sin(np.outer(block, omega) + phase)
        if amps is None:
            out[lo : lo + BLOCK] = tones.sum(axis=1) * amp
        else:
            out[lo : lo + BLOCK] = (tones * amps).sum(axis=1)
    return out


def body_vibration(
    model: VibrationModel,
    t: np.ndarray,
    speed_mps: np.ndarray,
    rng: np.random.Generator,
    rate_hz: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(x, z): the body's vibration acceleration along and normal to the track, m/s^2, as
    the anti-alias filter of a board at ``rate_hz`` passes it (None: unfiltered)."""
    t = np.asarray(t, dtype=np.float64)
    x = np.zeros_like(t)
    z = np.zeros_like(t)
    if not model.active:
        return x, z
    wt = 2.0 * math.pi * model.frequency_hz * t
    h = 1.0 if rate_hz is None else gain_of(model.frequency_hz, rate_hz)
    if model.vertical_mps2:
        z += (model.vertical_mps2 if h == 1.0 else model.vertical_mps2 * h) * np.sin(wt)
    if model.longitudinal_mps2:
        amp = model.longitudinal_mps2 if h == 1.0 else model.longitudinal_mps2 * h
        x += amp * np.sin(wt + math.radians(model.longitudinal_phase_deg))
    band = (model.broadband_low_hz, model.broadband_high_hz)
    # both axes draw their tones whatever the amplitudes, so one axis never shifts the other
    bz = multisine(t, *band, 1.0, rng, rate_hz)
    bx = multisine(t, *band, 1.0, rng, rate_hz)
    z += model.broadband_vertical_mps2 * bz
    x += model.broadband_longitudinal_mps2 * bx
    k = speed_factor(model, speed_mps)
    return x * k, z * k
