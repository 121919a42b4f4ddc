"""The car body's own modes, several at once: bounce (vertical translation on the secondary
suspension), pitch (rotation about the body's centre) and the first vertical bending mode
of the body shell.

Each mode is a damped oscillator driven by the track's broadband irregularity, so what the
body does in a mode is narrowband noise around its natural frequency: the response of
frequency f is |R(f)| = 1 / sqrt((1 - r^2)^2 + (2 zeta r)^2), r = f / fn, whose peak lies at
fn sqrt(1 - 2 zeta^2). It is generated as a seeded random-phase multisine of :data:`TONES`
tones, one in each equal sub-band of [fn max(0.3, 1 - 6 zeta), fn (1 + 6 zeta)], tone i of
amplitude proportional to |R(f_i)|, scaled so the mode's RMS is its ``rms`` (a pure function
of time, like devices.emulator.vibration's multisine: any block of samples alone, the same
bit for bit). The amplitude holds at ``reference_speed_mps`` and scales with
(|v| / reference)^exponent (none at standstill); each tone passes the board's anti-alias
filter at its gain (devices.emulator.antialias).

What the board feels (it sits on the body ``lever_m`` ahead of the pitch centre):

* bounce: the vertical acceleration z_b(t) (``rms`` in m/s^2);
* bending: the vertical acceleration of the shell at the board z_s(t) (m/s^2);
* pitch: the angle phi(t) (``rms`` in deg, nose up); the sensors' axes turn with it, so it
  adds to the body's pitch (gravity's component along the track becomes g sin(alpha + phi)),
  and the board, off the centre, moves vertically by lever_m phi(t): z += lever_m phi''(t).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from devices.emulator.antialias import gain
from devices.emulator.scenario import BodyModesModel, ModeModel

TONES = 48
"""Tones of one mode's multisine."""

BLOCK = 8192
"""Samples per block when evaluating a multisine."""

BAND_ZETAS = 6.0
"""A mode's tones span fn (1 +- BAND_ZETAS zeta) (low end at least 0.3 fn)."""


def response(freq_hz: np.ndarray, fn_hz: float, zeta: float) -> np.ndarray:
    """|R(f)| of a damped oscillator of natural frequency fn and damping ratio zeta."""
    r = np.asarray(freq_hz, dtype=np.float64) / fn_hz
    out: np.ndarray = 1.0 / np.sqrt((1.0 - r * r) ** 2 + (2.0 * zeta * r) ** 2)
    return out


@dataclass(frozen=True, slots=True)
class Tones:
    """A multisine: frequencies (Hz), amplitudes and phases (rad)."""

    freq: np.ndarray
    amp: np.ndarray
    phase: np.ndarray

    def at(self, t: np.ndarray, rate_hz: float | None, weights: np.ndarray) -> np.ndarray:
        """(len(t), k): column j is sum_i weights[i, j] amp_i sin(2 pi f_i t + phase_i),
        each tone times the anti-alias gain of a board at ``rate_hz`` (None: unfiltered).
        One sine per tone and instant serves every column."""
        amp = self.amp if rate_hz is None else self.amp * gain(self.freq, rate_hz)
        w = weights * amp[:, None]
        omega = 2.0 * math.pi * self.freq
        out = np.empty((len(t), w.shape[1]))
        for lo in range(0, len(t), BLOCK):
            block = t[lo : lo + BLOCK]
            out[lo : lo + BLOCK] = np.sin(np.outer(block, omega) + self.phase) @ w
        return out


def mode_tones(mode: ModeModel, rng: np.random.Generator) -> Tones:
    """The multisine of one mode, RMS ``mode.rms`` (tones drawn whatever the RMS, so one
    mode's amplitude never shifts another's draws)."""
    lo = mode.frequency_hz * max(0.3, 1.0 - BAND_ZETAS * mode.damping)
    hi = mode.frequency_hz * (1.0 + BAND_ZETAS * mode.damping)
    width = (hi - lo) / TONES
    freq = lo + (np.arange(TONES) + rng.random(TONES)) * width
    phase = 2.0 * math.pi * rng.random(TONES)
    shape = response(freq, mode.frequency_hz, mode.damping)
    amp = mode.rms * math.sqrt(2.0) * shape / math.sqrt(float(np.sum(shape * shape)))
    return Tones(freq, amp, phase)


@dataclass(frozen=True, slots=True)
class BodyModes:
    """The modes of one scenario, drawn once; evaluated at any times."""

    model: BodyModesModel
    tones: Tones  # bounce, pitch and bending, one after the other
    weights: np.ndarray  # (tones, 2): what each tone adds to z (m/s^2) and to the pitch (deg)

    @classmethod
    def draw(cls, model: BodyModesModel, rng: np.random.Generator) -> BodyModes:
        bounce, pitch, bending = (
            mode_tones(m, rng) for m in (model.bounce, model.pitch, model.bending)
        )
        parts = (bounce, pitch, bending)
        tones = Tones(
            *(np.concatenate([getattr(p, f) for p in parts]) for f in ("freq", "amp", "phase"))
        )
        n = TONES
        weights = np.zeros((3 * n, 2))
        weights[:n, 0] = 1.0  # bounce: vertical
        weights[2 * n :, 0] = 1.0  # bending: vertical at the board
        omega = 2.0 * math.pi * pitch.freq
        weights[n : 2 * n, 0] = -model.lever_m * math.radians(1.0) * omega * omega  # L phi''
        weights[n : 2 * n, 1] = 1.0  # the pitch angle itself
        return cls(model, tones, weights)

    def speed_factor(self, speed_mps: np.ndarray) -> np.ndarray:
        r = np.abs(np.asarray(speed_mps, dtype=np.float64)) / self.model.reference_speed_mps
        return np.where(r > 0.0, r**self.model.speed_exponent, 0.0)

    def felt(
        self, t: np.ndarray, speed_mps: np.ndarray, rate_hz: float | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """(z m/s^2, pitch deg): the board's vertical acceleration from bounce, bending and
        the pitch's lever arm, and the body's pitch angle of the pitch mode."""
        k = self.speed_factor(speed_mps)
        out = self.tones.at(np.asarray(t, dtype=np.float64), rate_hz, self.weights)
        return out[:, 0] * k, out[:, 1] * k


__all__ = [
    "BAND_ZETAS",
    "TONES",
    "BodyModes",
    "Tones",
    "mode_tones",
    "response",
]
