"""Track irregularity fixed in position: a rail joint or a switch is felt at the same metre
of the line in every run, harder the faster the train passes it.

Each axle that passes a feature at position p gives the wheel a vertical velocity change
proportional to the speed (a dip of angle 2 beta turns the wheel's path by 2 beta, so its
vertical velocity changes by 2 beta v): an impulse the body answers with a damped ring at
the board, and which the suspension takes back, since a dip or a joint leaves the wheel at
the height it had:

    z(t) = A (|v_p| / v_ref)^n exp(-zeta wn tau) (sin(wd tau) - wd zeta^2 tau),

tau = t - t_p >= 0, wd = wn sqrt(1 - zeta^2). The second term (peak zeta / e of the
ring's, at tau = 1 / (zeta wn)) makes the integral exactly 0: the body's vertical velocity
comes back to rest. The ring alone left the body rising by A wd / wn^2 a passage: on
jointed rail a steady 0.005-0.02 m/s^2 upwards, which reads as gradient and as the board's
pitch. t_p is the instant the axle (``axles_m`` ahead of the board, + forwards) is at p
and v_p the train's speed then; A is the feature's ``amplitude_mps2`` (negative: the board
drops first). The passages are found once from the
whole run's motion (a 10 ms grid, bisection to 1 us, one Newton step), so the disturbance is a pure
function of time: any block alone, the same bit for bit. A passage backwards counts too.

Periodic joints (jointed rail, ``joint_spacing_m`` > 0) sit at joint_start_m + k spacing;
joint k's amplitude is drawn uniform in joint_amplitude_mps2 (1 +- joint_spread) from its
own generator seeded by ``track_seed`` and k alone: the line's joints are the same whatever
the run's seed, speed profile or extent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.antialias import gain
from devices.emulator.motion import scenario_motion
from devices.emulator.scenario import IrregularityModel, Scenario

GRID_S = 0.01
"""Step of the grid the passages are first located on."""

RESOLUTION_S = 1e-6
"""The passages' instants after bisection."""

DECAYED = 20.7  # e^-20.7 < 1e-9: a ring older than this many 1 / (zeta wn) is gone

JOINT_INDEX0 = 1 << 40
"""Joint k's generator index is JOINT_INDEX0 + k (k may be negative)."""


@dataclass(frozen=True, slots=True)
class Rings:
    """Every passage of the run: onset (s), amplitude (m/s^2), wn and zeta, sorted by
    onset."""

    t0: np.ndarray
    amp: np.ndarray
    wn: np.ndarray
    zeta: np.ndarray

    def at(self, t: np.ndarray, rate_hz: float | None) -> np.ndarray:
        """The board's vertical acceleration at times t, each ring times the anti-alias gain
        of a board at ``rate_hz`` at its frequency (None: unfiltered)."""
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros_like(t)
        if not len(t) or not len(self.t0):
            return out
        wd = self.wn * np.sqrt(1.0 - self.zeta**2)
        amp = self.amp if rate_hz is None else self.amp * gain(wd / (2 * math.pi), rate_hz)
        end = self.t0 + DECAYED / (self.zeta * self.wn)
        live = np.nonzero((self.t0 <= t[-1]) & (end >= t[0]))[0]
        for k in live:
            lo, hi = np.searchsorted(t, [self.t0[k], end[k]])
            tau = t[lo:hi] - self.t0[k]
            decay = np.exp(-self.zeta[k] * self.wn[k] * tau)
            sigma = self.zeta[k] * self.wn[k]
            shape = np.sin(wd[k] * tau) - (wd[k] * sigma**2 / self.wn[k] ** 2) * tau
            out[lo:hi] += amp[k] * decay * shape
        return out


def features(m: IrregularityModel, lo_m: float, hi_m: float) -> np.ndarray:
    """(position, amplitude, frequency, damping) rows of every feature in [lo_m, hi_m]:
    the listed ones and the periodic joints there."""
    rows = [
        (f.position_m, f.amplitude_mps2, f.frequency_hz, f.damping)
        for f in m.features
        if lo_m <= f.position_m <= hi_m
    ]
    if m.joint_spacing_m > 0.0 and m.joint_amplitude_mps2:
        first = math.ceil((lo_m - m.joint_start_m) / m.joint_spacing_m)
        last = math.floor((hi_m - m.joint_start_m) / m.joint_spacing_m)
        for k in range(first, last + 1):
            u = fx.rng_for(m.track_seed, fx.LAYER_TRACK, JOINT_INDEX0 + k).random()
            amp = m.joint_amplitude_mps2 * (1.0 + m.joint_spread * (2.0 * u - 1.0))
            rows.append((m.joint_start_m + k * m.joint_spacing_m, amp, m.frequency_hz, m.damping))
    return np.array(rows, dtype=np.float64).reshape(-1, 4)


def passages(
    sc: Scenario, offset_m: float, at_m: np.ndarray, grid: np.ndarray, x: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(instants s, feature index) at which the point ``offset_m`` ahead of the board is at
    one of the positions ``at_m``, over the whole run (every crossing, either way), from
    the board's positions ``x`` on ``grid``: the point is at p between two grid instants
    where p is in (min, max] of its positions there; bisection and a Newton step refine."""
    x = x + offset_m
    order = np.argsort(at_m, kind="stable")
    ps = at_m[order]
    lo, hi = np.minimum(x[:-1], x[1:]), np.maximum(x[:-1], x[1:])
    first = np.searchsorted(ps, lo, side="right")
    count = np.searchsorted(ps, hi, side="right") - first
    step = np.repeat(np.arange(len(lo)), count)  # one row per crossing, in time order
    if not len(step):
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    within = np.arange(len(step)) - np.repeat(np.cumsum(count) - count, count)
    j = order[first[step] + within]
    p = at_m[j]
    a, b = grid[step], grid[step + 1]
    before = x[step] >= p
    while float(np.max(b - a)) > RESOLUTION_S:  # bisect every crossing at once
        mid = 0.5 * (a + b)
        same = (scenario_motion(sc, mid).position_m + offset_m >= p) == before
        a, b = np.where(same, mid, a), np.where(same, b, mid)
    mid = 0.5 * (a + b)
    at = scenario_motion(sc, mid)  # one Newton step: exact where the train moves
    v = at.speed_mps
    moving = np.abs(v) > 1e-3
    dt = (at.position_m + offset_m - p) / np.where(moving, v, 1.0)
    return np.where(moving & (np.abs(dt) <= RESOLUTION_S), mid - dt, mid), j


def rings(sc: Scenario) -> Rings:
    """Every axle's passage over every feature the run reaches."""
    m = sc.track_irregularity
    grid = np.arange(0.0, sc.duration_s + GRID_S, GRID_S)
    x = scenario_motion(sc, grid).position_m
    reach = max(abs(a) for a in m.axles_m)
    rows = features(m, float(x.min()) - reach, float(x.max()) + reach)
    t0s, amps, wns, zetas = [], [], [], []
    for offset in m.axles_m:
        t0, j = passages(sc, offset, rows[:, 0], grid, x)
        v = np.abs(scenario_motion(sc, t0).speed_mps) / m.reference_speed_mps
        t0s.append(t0)
        amps.append(rows[j, 1] * np.where(v > 0.0, v**m.speed_exponent, 0.0))
        wns.append(2.0 * math.pi * rows[j, 2])
        zetas.append(rows[j, 3])
    t0 = np.concatenate(t0s)
    order = np.argsort(t0, kind="stable")
    return Rings(
        t0[order],
        np.concatenate(amps)[order],
        np.concatenate(wns)[order],
        np.concatenate(zetas)[order],
    )


__all__ = ["GRID_S", "Rings", "features", "passages", "rings"]
