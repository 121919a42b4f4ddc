"""The board's anti-alias filter and decimation: what a sigma-delta ADC's digital filter does
to the signal before the MCU sends one sample per output period.

Each channel's delta-sigma modulator runs at :data:`OVERSAMPLING` times the configured
sample rate fs; its decimator is a sinc^3 filter (a third-order CIC: three cascaded moving
averages of :data:`OVERSAMPLING` modulator samples, 3M - 2 taps), and keeps every M-th
output. Its amplitude response at frequency f is

    H(f) = | sin(pi f / fs) / (M sin(pi f / (M fs))) | ^ 3

with nulls at every multiple of fs, so a tone that would alias onto the output band is
suppressed: a 40 Hz tone on a 50 Hz board is kept at H = 0.0128 (it would alias to 10 Hz),
a 2 Hz tone at 0.992. The filter is symmetric (linear phase); the board stamps each sample
with the centre of its filter window (ICD 1.1: the timestamp is the board time of the
sampling instant the sample stands for), so it adds no delay and no phase.

The emulator's signal is a slow world (track, motion, v^2/R) plus sums of sinusoids (body
vibration and modes, each sensor's mounting vibration). A linear filter scales a sinusoid by
H(f), so each sinusoid is generated with its amplitude times :func:`gain` -- exactly what
filtering the modulator's samples would give, and the same in any block of samples, so the
chunked run equals the whole run with nothing to carry. An amplitude that follows the
speed is taken at the sampling instant (it changes little over the 3/fs window). The slow
world is taken as is: below 1 Hz H differs from 1 by less than 0.2 % at 50 Hz (a jerk-free
acceleration step is felt as a step, not as the filter's 3/fs ramp). The white noise of
each sensor is stated at the output rate (what the filter lets through), so it is drawn
there.
"""

from __future__ import annotations

import math

import numpy as np

OVERSAMPLING = 64
"""M: modulator samples per output sample."""

ORDER = 3
"""The sinc filter's order (cascaded moving averages)."""


def gain(freq_hz: float | np.ndarray, rate_hz: float, enabled: bool = True) -> np.ndarray:
    """|H(f)| of the sinc^3 decimator of a board sampling at ``rate_hz`` (1 when disabled)."""
    f = np.abs(np.asarray(freq_hz, dtype=np.float64))
    if not enabled:
        return np.ones_like(f)
    x = math.pi * f / rate_hz
    num = np.sin(x)
    den = OVERSAMPLING * np.sin(x / OVERSAMPLING)
    safe = np.where(den == 0.0, 1.0, den)
    h = np.where(den == 0.0, 1.0, num / safe)
    out: np.ndarray = np.abs(h) ** ORDER
    return out


def gain_of(freq_hz: float, rate_hz: float, enabled: bool = True) -> float:
    """:func:`gain` of one frequency, as a float."""
    return float(gain(freq_hz, rate_hz, enabled))
