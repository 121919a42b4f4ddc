"""The simulated world: track profile, train motion and what each sensor feels (ICD section 3).

Pure, vectorised functions of time or position; no randomness beyond the generator passed
in, no I/O. Conventions:

* position x grows in the car's nose direction; ``gradient_permil`` is positive uphill in
  that direction, and ``accel_mps2`` is d(speed)/dt with speed signed the same way, so the
  ICD formula holds whether the train runs forwards or backwards;
* the vertical curve between two segments is a parabola (what railways build): the gradient
  changes linearly with distance over ``vertical_curve_m`` centred on the segment boundary;
* on a vertical curve the car also accelerates towards the curve's centre, v^2/R normal to
  the track (``vertical_curve_accel``): a sag presses the car down onto its bogies, a crest
  lifts it; 1/R = d(alpha)/dx;
* every sensor reads the car body's specific force (acceleration minus gravity) projected
  on its own axis: f_x cos(theta) + f_z sin(theta), with f_x along the track and f_z normal
  to it. Without body motion f_x = a + g sin(alpha) and f_z = g cos(alpha), which is the ICD
  formula a cos(theta) + g sin(alpha + theta).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from devices.emulator.scenario import BoardModel, ChannelModel, TrackSegment, TrainPhase
from protocol.layout import CODE_MAX, CODE_MIN, NOMINAL_SCALE


def gradient_profile(
    track: tuple[TrackSegment, ...], default_curve_m: float, x: np.ndarray
) -> np.ndarray:
    """Gradient (per mille) at positions x (m) along consecutive segments from position 0.

    Before position 0 the first segment's gradient holds, after the last segment the last
    one's. Each change is spread linearly over its vertical curve, shortened where needed so
    that a curve never reaches past the middle of a neighbouring segment.
    """
    x = np.asarray(x, dtype=np.float64)
    if not track:
        return np.zeros_like(x)
    out = np.full_like(x, track[0].gradient_permil)
    boundary = 0.0
    for prev, seg in itertools.pairwise(track):
        boundary += prev.length_m
        step = seg.gradient_permil - prev.gradient_permil
        if step == 0.0:
            continue
        curve = seg.vertical_curve_m if seg.vertical_curve_m is not None else default_curve_m
        curve = min(curve, prev.length_m, seg.length_m)
        if curve <= 0.0:
            out += np.where(x >= boundary, step, 0.0)
        else:
            out += step * np.clip((x - boundary) / curve + 0.5, 0.0, 1.0)
    return out


def gradient_slope(
    track: tuple[TrackSegment, ...], default_curve_m: float, x: np.ndarray
) -> np.ndarray:
    """d(gradient)/dx (per mille per metre) at positions x: the derivative of
    :func:`gradient_profile` (an abrupt change, vertical curve 0, has none)."""
    x = np.asarray(x, dtype=np.float64)
    out = np.zeros_like(x)
    boundary = 0.0
    for prev, seg in itertools.pairwise(track):
        boundary += prev.length_m
        step = seg.gradient_permil - prev.gradient_permil
        curve = seg.vertical_curve_m if seg.vertical_curve_m is not None else default_curve_m
        curve = min(curve, prev.length_m, seg.length_m)
        if step == 0.0 or curve <= 0.0:
            continue
        inside = np.abs(x - boundary) < 0.5 * curve
        out += np.where(inside, step / curve, 0.0)
    return out


def curve_normal_accel(
    speed_mps: np.ndarray, gradient_permil: np.ndarray, slope_permil_per_m: np.ndarray
) -> np.ndarray:
    """v^2/R normal to the track (m/s^2, positive towards the car's roof, i.e. in a sag).

    alpha = atan(G / 1000), so 1/R = d(alpha)/dx = (G' / 1000) / (1 + (G / 1000)^2)."""
    tan_a = np.asarray(gradient_permil) / 1000.0
    return np.asarray(speed_mps) ** 2 * (np.asarray(slope_permil_per_m) / 1000.0) / (1.0 + tan_a**2)


def board_temperature(board: BoardModel, t: np.ndarray) -> np.ndarray:
    """Board temperature (deg C) at run times t (s): from ``temperature_c`` towards
    ``temperature_end_c`` with time constant ``temperature_tau_s`` (a warming enclosure)."""
    t = np.asarray(t, dtype=np.float64)
    t0 = float(board.temperature_c)
    if board.temperature_end_c is None:
        return np.full_like(t, t0)
    end = board.temperature_end_c
    temp: np.ndarray = end + (t0 - end) * np.exp(-np.maximum(t, 0.0) / board.temperature_tau_s)
    return temp


@dataclass(frozen=True, slots=True)
class Motion:
    accel_mps2: np.ndarray
    speed_mps: np.ndarray
    position_m: np.ndarray


def train_motion(phases: tuple[TrainPhase, ...], v0: float, x0: float, t: np.ndarray) -> Motion:
    """Acceleration, speed and position at times t (s), exact piecewise-quadratic kinematics.

    Each phase accelerates at a constant rate for its duration; the speed is held after the
    last phase. Braking rule: a phase never takes the speed through zero unless it sets
    ``allow_reverse`` -- when the speed reaches 0 the train stops and stays at rest (a = 0)
    until the phase ends. A train at rest counts as running forwards, so without
    ``allow_reverse`` a negative acceleration from standstill leaves it standing.
    """
    t = np.asarray(t, dtype=np.float64)
    acc = np.zeros_like(t)
    v = np.full_like(t, v0)
    x = x0 + v0 * t
    t0, vs, xs = 0.0, v0, x0
    for ph in phases:
        a = ph.accel_mps2
        run = ph.duration_s  # how long the train actually accelerates in this phase
        if not ph.allow_reverse and a != 0.0:
            forward = vs >= 0.0
            if (forward and a < 0.0) or (not forward and a > 0.0):
                run = min(run, abs(vs / a))
        sel = t >= t0
        tau = np.minimum(t[sel] - t0, run)
        acc[sel] = np.where(t[sel] - t0 < run, a, 0.0)
        v[sel] = vs + a * tau
        x[sel] = xs + vs * tau + 0.5 * a * tau * tau  # tau stops growing once stopped
        t1 = t0 + ph.duration_s
        v1 = vs + a * run if run == ph.duration_s else 0.0  # stopped: exactly, so the
        # next phase's direction test cannot read a rounding residue (-5e-17) as reversing
        x1 = xs + vs * run + 0.5 * a * run * run
        after = t >= t1
        acc[after] = 0.0
        v[after] = v1
        x[after] = x1 + v1 * (t[after] - t1)
        t0, vs, xs = t1, v1, x1
    return Motion(acc, v, x)


def specific_force(
    accel_mps2: np.ndarray, gradient_permil: np.ndarray, g: float, angle_deg: float
) -> np.ndarray:
    """What an ideal sensor pitched by angle_deg reads: a*cos(theta) + g*sin(alpha + theta)."""
    theta = math.radians(angle_deg)
    alpha = np.arctan(np.asarray(gradient_permil) / 1000.0)
    return accel_mps2 * math.cos(theta) + g * np.sin(alpha + theta)


def body_specific_force(
    accel_mps2: np.ndarray,
    gradient_permil: np.ndarray,
    g: float,
    angle_deg: float,
    extra_x: np.ndarray | float = 0.0,
    extra_z: np.ndarray | float = 0.0,
) -> np.ndarray:
    """:func:`specific_force` plus body accelerations along (x) and normal to (z) the track
    (vibration, v^2/R), each projected on the sensor's axis: x cos(theta) + z sin(theta)."""
    theta = math.radians(angle_deg)
    base = specific_force(accel_mps2, gradient_permil, g, angle_deg)
    return base + (np.asarray(extra_x) * math.cos(theta) + np.asarray(extra_z) * math.sin(theta))


def sensor_output(
    ideal_mps2: np.ndarray,
    ch: ChannelModel,
    t: np.ndarray,
    rng: np.random.Generator,
    temperature_rise_k: np.ndarray | None = None,
    vibration_gain: float = 1.0,
) -> np.ndarray:
    """The as-built sensor: scale error, bias (drifting with the board's temperature rise
    since the start), vibration of its own mounting (times the anti-alias filter's
    ``vibration_gain`` at its frequency) and white noise on the ideal value."""
    out = ideal_mps2 * (1.0 + ch.scale_error) + ch.bias_mps2
    if ch.bias_tempco_mps2_per_k and temperature_rise_k is not None:
        out = out + ch.bias_tempco_mps2_per_k * temperature_rise_k
    if ch.vibration_mps2 and ch.vibration_hz:
        phase = math.radians(ch.vibration_phase_deg)
        amp = ch.vibration_mps2 if vibration_gain == 1.0 else ch.vibration_mps2 * vibration_gain
        out = out + amp * np.sin(2.0 * math.pi * ch.vibration_hz * t + phase)
    if ch.noise_mps2:
        out = out + ch.noise_mps2 * rng.standard_normal(len(out))
    return out


def quantise(value_mps2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Int24 codes at the nominal scale (offset 0), rounded to nearest, clipped at the rails.

    Returns (codes int32, over_range bool): the ADC sets OVR when it had to clip.
    """
    raw = np.rint(np.asarray(value_mps2) / NOMINAL_SCALE)
    over = (raw > CODE_MAX) | (raw < CODE_MIN)
    return np.clip(raw, CODE_MIN, CODE_MAX).astype(np.int32), over
