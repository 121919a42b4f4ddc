"""Jerk-limited train motion: acceleration ramps between phases, exact piecewise-cubic kinematics.

A real train never steps its acceleration: traction and brake controllers ramp it at a
limited jerk (metros about 0.5-1 m/s^3, for comfort). The motion is built once as a short
list of pieces, each with constant jerk from a known state (t0, a0, v0, x0), and then
evaluated at any times, so a long run is cheap and any slice of time can be evaluated on
its own.

Rules (docs/EMULATOR.md):

* each phase ramps the acceleration from where it is towards the phase's ``accel_mps2`` at
  the jerk limit, then holds it; a phase too short for the ramp ends part way;
* braking rule (as without a jerk limit): a phase never takes the speed through zero unless
  it sets ``allow_reverse``. With a jerk limit the train eases off its brake at the jerk
  limit so that speed and acceleration reach zero together (the ease-off starts when the
  speed is a^2 / 2j); it then stands (a = 0) until the phase ends;
* after the last phase the acceleration ramps to zero and the speed is held.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from devices.emulator.scenario import Scenario, TrainPhase
from devices.emulator.world import Motion, train_motion

_EPS = 1e-12


@dataclass(frozen=True, slots=True)
class Pieces:
    """Constant-jerk pieces: piece k starts at t0[k] with acceleration a0, speed v0, position
    x0 and holds jerk j until the next piece starts."""

    t0: np.ndarray
    a0: np.ndarray
    j: np.ndarray
    v0: np.ndarray
    x0: np.ndarray

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(acceleration, speed, position) at times t (s)."""
        t = np.asarray(t, dtype=np.float64)
        k = np.clip(np.searchsorted(self.t0, t, side="right") - 1, 0, len(self.t0) - 1)
        tau = t - self.t0[k]
        a0, j, v0 = self.a0[k], self.j[k], self.v0[k]
        acc = a0 + j * tau
        v = v0 + a0 * tau + 0.5 * j * tau * tau
        x = self.x0[k] + v0 * tau + 0.5 * a0 * tau * tau + j * tau**3 / 6.0
        before = t < self.t0[0]  # before the run: the initial speed, no acceleration
        if before.any():
            acc = np.where(before, 0.0, acc)
            v = np.where(before, self.v0[0], v)
            x = np.where(before, self.x0[0] + self.v0[0] * (t - self.t0[0]), x)
        return acc, v, x


class _Builder:
    def __init__(self, v0: float, x0: float) -> None:
        self.t, self.a, self.v, self.x = 0.0, 0.0, v0, x0
        self.rows: list[tuple[float, float, float, float, float]] = []

    def run(self, dur: float, jerk: float) -> None:
        """Hold ``jerk`` for ``dur`` seconds from the current state."""
        if dur <= 0.0:
            return
        self.rows.append((self.t, self.a, jerk, self.v, self.x))
        a, v = self.a, self.v
        self.x += v * dur + 0.5 * a * dur * dur + jerk * dur**3 / 6.0
        self.v += a * dur + 0.5 * jerk * dur * dur
        self.a += jerk * dur
        self.t += dur

    def no_reversal(self, s: float) -> None:
        """A rounding step past zero speed is no reversal: clamp it to rest."""
        if s * self.v < 0.0:
            self.v = 0.0

    def stop(self) -> None:
        self.a, self.v = 0.0, 0.0

    def pieces(self) -> Pieces:
        rows = self.rows or [(0.0, self.a, 0.0, self.v, self.x)]
        cols = np.array(rows, dtype=np.float64).T
        return Pieces(*cols)


def _phase(b: _Builder, target: float, duration: float, jerk: float, reverse: bool) -> None:
    """Add one phase (jerk = inf: acceleration steps). Works in the direction of motion."""
    t_end = b.t + duration
    stopping = False
    s = -1.0 if b.v < 0.0 else 1.0  # the way it runs; a train at rest counts as forwards
    for _ in range(16):  # a phase is at most ramp, hold, ease-off, rest
        rem = t_end - b.t
        if rem <= _EPS:
            break
        if reverse:
            s = -1.0 if b.v < 0.0 else 1.0
        an, vn, tn = s * b.a, s * b.v, s * target
        if not reverse:
            if vn <= 0.0 and an <= 0.0 and tn <= 0.0:  # standing, asked to brake: stays
                b.stop()
                b.run(rem, 0.0)
                break
            finite = math.isfinite(jerk)
            if an < 0.0 and finite and (stopping or vn <= an * an / (2.0 * jerk) + _EPS):
                disc = an * an - 2.0 * jerk * vn
                tau = (-an - math.sqrt(disc)) / jerk if disc > 0.0 else -an / jerk
                if tau >= rem:
                    b.run(rem, s * jerk)
                    break
                b.run(tau, s * jerk)
                b.stop()
                b.run(t_end - b.t, 0.0)  # stopped: stands until the phase ends
                break
            if an < 0.0 and not finite and an == tn:
                tau = vn / -an
                if tau < rem:
                    b.run(tau, 0.0)
                    b.stop()
                    b.run(t_end - b.t, 0.0)
                    break
        if an != tn:
            if not math.isfinite(jerk):
                b.a = target
                continue
            jn = jerk if tn > an else -jerk
            dur = (tn - an) / jn
            if not reverse and jn < 0.0:  # braking harder: where must the ease-off begin?
                tau = (an + math.sqrt(max(an * an / 2.0 + jerk * vn, 0.0))) / jerk
                if tau < min(dur, rem):
                    b.run(tau, s * jn)
                    stopping = True
                    continue
            if dur >= rem:
                b.run(rem, s * jn)
                if not reverse:
                    b.no_reversal(s)
                break
            b.run(dur, s * jn)
            b.a = target
            if not reverse:
                b.no_reversal(s)
            continue
        if not reverse and tn < 0.0:  # hold the brake until the ease-off point
            tau = (vn - tn * tn / (2.0 * jerk)) / -tn
            if tau < rem:
                b.run(max(tau, 0.0), 0.0)
                stopping = True
                continue
        b.run(rem, 0.0)
        break
    b.t = t_end


def jerk_limited_pieces(
    phases: tuple[TrainPhase, ...], default_jerk: float, v0: float, x0: float, t_max: float
) -> Pieces:
    """The motion of ``phases`` as constant-jerk pieces up to ``t_max`` (s).

    ``default_jerk`` applies to phases without their own ``jerk_mps3``; 0 means no limit
    (the acceleration steps)."""
    b = _Builder(v0, x0)
    for ph in phases:
        j = ph.jerk_mps3 if ph.jerk_mps3 is not None else default_jerk
        _phase(b, ph.accel_mps2, ph.duration_s, j if j > 0.0 else math.inf, ph.allow_reverse)
    tail = max(t_max - b.t, 0.0) + 1.0
    last = phases[-1] if phases else None
    j_last = last.jerk_mps3 if last and last.jerk_mps3 is not None else default_jerk
    _phase(b, 0.0, tail, j_last if j_last > 0.0 else math.inf, False)
    return b.pieces()


def has_jerk_limit(sc: Scenario) -> bool:
    return sc.jerk_mps3 > 0.0 or any(ph.jerk_mps3 for ph in sc.train)


def scenario_motion(sc: Scenario, t: np.ndarray) -> Motion:
    """The scenario's train at times t: jerk-limited pieces when a jerk limit is set, else
    the constant-acceleration phases of :func:`devices.emulator.world.train_motion`."""
    if not has_jerk_limit(sc):
        return train_motion(sc.train, sc.initial_speed_mps, sc.initial_position_m, t)
    pieces = jerk_limited_pieces(
        sc.train, sc.jerk_mps3, sc.initial_speed_mps, sc.initial_position_m, sc.duration_s
    )
    return Motion(*pieces.evaluate(t))
