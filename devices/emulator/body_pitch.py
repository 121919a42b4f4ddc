"""Car-body pitch relative to the track: the secondary suspension under traction, braking
and load. The board sits on the body, so every sensor's axis turns with it and the pitch
reads as gradient (1 deg = 17.5 permil).

The body is a second-order system (natural frequency f, damping ratio zeta < 1, unit DC
gain) driven by u(t) = C a(t) + L(t): the compliance C (deg per m/s^2, nose up while the
train accelerates forwards: the inertial force acts at the body's centre of gravity, above
the traction rods) times the train's acceleration, plus the static pitch of the load. L
changes only at stations: at every stop of at least ``min_dwell_s`` the load's pitch moves
by a normal draw of standard deviation ``load_step_deg``, as a ramp over the middle 60 % of
the dwell (doors open, passengers board, doors close).

u is piecewise linear (the motion's acceleration is, jerk-limited or stepping; so is L), so
the response is exact and a pure function of time: at knot k the input's value steps by
du_k and its slope by dj_k, and

    y(t) = u(t) - (2 zeta / wn) u'(t) + sum_k [du_k Ts(t - t_k) + dj_k Tr(t - t_k)]

with Ts, Tr the decaying parts of the unit step and unit ramp responses (the body is at
rest before the run). A knot's transient is dropped once it has decayed below 1e-12.
"""

from __future__ import annotations

import math

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.motion import Pieces, jerk_limited_pieces
from devices.emulator.scenario import BodyPitchModel, Scenario

STATION_RAMP = (0.2, 0.8)
"""The load changes over this part of a station's dwell (doors open after the stop, close
before the departure)."""

_DECAYED = 27.7  # e^-27.7 < 1e-12: a transient older than this many 1/(zeta wn) is gone


def step_transient(tau: np.ndarray, zeta: float, wn: float) -> np.ndarray:
    """Unit step response minus 1: -e^(-zeta wn tau) (cos(wd tau) + zeta/sqrt(1-zeta^2) sin)."""
    wd = wn * math.sqrt(1.0 - zeta * zeta)
    e = np.exp(-zeta * wn * tau)
    out: np.ndarray = -e * (np.cos(wd * tau) + (zeta * wn / wd) * np.sin(wd * tau))
    return out


def ramp_transient(tau: np.ndarray, zeta: float, wn: float) -> np.ndarray:
    """Unit ramp response minus (tau - 2 zeta / wn), the integral of 1 + step_transient."""
    wd = wn * math.sqrt(1.0 - zeta * zeta)
    e = np.exp(-zeta * wn * tau)
    out: np.ndarray = e * (
        (2.0 * zeta / wn) * np.cos(wd * tau) + ((2.0 * zeta * zeta - 1.0) / wd) * np.sin(wd * tau)
    )
    return out


class BodyPitch:
    """The body's pitch (deg, nose up positive) at any run times of one scenario."""

    def __init__(
        self,
        sc: Scenario,
        stations: list[tuple[float, float]] | None = None,
        steps: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        """``stations`` as :func:`scenario_stations` (computed if not given); ``steps``
        (times, deg): further steps of the load's pitch (passengers boarding)."""
        m: BodyPitchModel = sc.body_pitch
        self.model = m
        self.wn = 2.0 * math.pi * m.frequency_hz
        self.zeta = m.damping_ratio
        p = _pieces(sc)
        c = m.compliance_deg_per_mps2
        # the acceleration's knots: value and slope changes at each piece's start
        a_end = np.concatenate(([0.0], p.a0[:-1] + p.j[:-1] * np.diff(p.t0)))
        j_before = np.concatenate(([0.0], p.j[:-1]))
        times = [p.t0]
        du = [c * (p.a0 - a_end)]
        dj = [c * (p.j - j_before)]
        if stations is None:
            stations = scenario_stations(sc)
        self.stations = stations
        if steps is not None and len(steps[0]):
            times.append(np.asarray(steps[0], dtype=np.float64))
            du.append(np.asarray(steps[1], dtype=np.float64))
            dj.append(np.zeros(len(steps[0])))
        rng = fx.rng_for(sc.seed, fx.LAYER_BODY_PITCH)
        self.load_steps = m.load_step_deg * rng.standard_normal(len(self.stations))
        for (t0, t1), step in zip(self.stations, self.load_steps, strict=True):
            r0 = t0 + STATION_RAMP[0] * (t1 - t0)
            r1 = t0 + STATION_RAMP[1] * (t1 - t0)
            rate = step / (r1 - r0)
            times.append(np.array([r0, r1]))
            du.append(np.zeros(2))
            dj.append(np.array([rate, -rate]))
        t_all = np.concatenate(times)
        order = np.argsort(t_all, kind="stable")
        self.t_k = t_all[order]
        self.du = np.concatenate(du)[order]
        self.dj = np.concatenate(dj)[order]
        # the input's value and slope just after each knot
        gaps = np.diff(self.t_k, prepend=self.t_k[0] if len(self.t_k) else 0.0)
        slope = np.cumsum(self.dj)
        slope_before = np.concatenate(([0.0], slope[:-1]))
        self.u_k = np.cumsum(self.du + slope_before * gaps)
        self.s_k = slope

    def input_deg(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(u, u') at times t: the pitch the body settles to, and its rate."""
        t = np.asarray(t, dtype=np.float64)
        k = np.searchsorted(self.t_k, t, side="right") - 1
        known = k >= 0
        kk = np.maximum(k, 0)
        u = np.where(known, self.u_k[kk] + self.s_k[kk] * (t - self.t_k[kk]), 0.0)
        s = np.where(known, self.s_k[kk], 0.0)
        return u, s

    def deg(self, t: np.ndarray) -> np.ndarray:
        """The body's pitch relative to the track (deg) at run times t (sorted)."""
        t = np.asarray(t, dtype=np.float64)
        if not self.model.enabled:
            return np.zeros_like(t)
        u, s = self.input_deg(t)
        y = self.model.static_deg + u - (2.0 * self.zeta / self.wn) * s
        horizon = _DECAYED / (self.zeta * self.wn)
        for tk, du, dj in zip(self.t_k, self.du, self.dj, strict=True):
            if du == 0.0 and dj == 0.0:
                continue
            lo, hi = np.searchsorted(t, [tk, tk + horizon])
            if lo == hi:
                continue
            tau = t[lo:hi] - tk
            y[lo:hi] += du * step_transient(tau, self.zeta, self.wn) + dj * ramp_transient(
                tau, self.zeta, self.wn
            )
        out: np.ndarray = y
        return out


def _pieces(sc: Scenario) -> Pieces:
    return jerk_limited_pieces(
        sc.train, sc.jerk_mps3, sc.initial_speed_mps, sc.initial_position_m, sc.duration_s
    )


def scenario_stations(sc: Scenario) -> list[tuple[float, float]]:
    """The run's stations: its stops of at least ``[body_pitch] min_dwell_s``."""
    p = _pieces(sc)
    return stations(p.t0, p.a0, p.j, p.v0, sc.body_pitch.min_dwell_s, sc.duration_s)


def stations(
    t0: np.ndarray, a0: np.ndarray, j: np.ndarray, v0: np.ndarray, min_dwell_s: float, end_s: float
) -> list[tuple[float, float]]:
    """The stops (start, end) of at least ``min_dwell_s`` within [0, end_s): consecutive
    pieces at rest (no speed, acceleration or jerk), merged."""
    rest = (v0 == 0.0) & (a0 == 0.0) & (j == 0.0)
    out: list[tuple[float, float]] = []
    k, n = 0, len(t0)
    while k < n:
        if not rest[k]:
            k += 1
            continue
        first = k
        while k < n and rest[k]:
            k += 1
        start = float(t0[first])
        stop = min(float(t0[k]) if k < n else math.inf, end_s)
        if stop - start >= min_dwell_s:
            out.append((start, stop))
    return out


def pitched_specific_force(
    accel_mps2: np.ndarray,
    gradient_permil: np.ndarray,
    g: float,
    angle_deg: float,
    pitch_deg: np.ndarray,
    extra_x: np.ndarray | float = 0.0,
    extra_z: np.ndarray | float = 0.0,
) -> np.ndarray:
    """What a sensor at ``angle_deg`` on a body pitched by ``pitch_deg`` reads: the body's
    specific force in the track frame (f_x = a + g sin(alpha) + x, f_z = g cos(alpha) + z)
    on the axis at theta + pitch: f_x cos(theta + pitch) + f_z sin(theta + pitch)."""
    alpha = np.arctan(np.asarray(gradient_permil) / 1000.0)
    th = np.radians(angle_deg + np.asarray(pitch_deg))
    fx_ = np.asarray(accel_mps2) + g * np.sin(alpha) + extra_x
    fz = g * np.cos(alpha) + extra_z
    out: np.ndarray = fx_ * np.cos(th) + fz * np.sin(th)
    return out


__all__ = [
    "STATION_RAMP",
    "BodyPitch",
    "pitched_specific_force",
    "ramp_transient",
    "scenario_stations",
    "stations",
    "step_transient",
]
