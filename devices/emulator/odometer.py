"""The train's odometer as the bench sees it on SPEED_REF: latency, wheel slide and slip,
white noise, quantisation (ICD section 1.3).

A wheel-based odometer measures the speed of a wheel, not of the train. Braking on a wet
rail the wheel slides: it turns slower than the train rolls, until the wheel-slide
protection (WSP) releases the brake and the wheel spins back up; then the brake is applied
again and the next cycle begins. Motoring, the wheel slips the other way. Each cycle is a
sawtooth of the speed error: it grows linearly over the first :data:`RISE` of the period
to its depth and recovers linearly over the rest.

Slide (slip) happens only inside the low-adhesion window while the train brakes
(accelerates) harder than the configured threshold; the cycle clock starts at the first
SPEED_REF measurement that finds it so, and each such stretch starts a new series of
cycles. A sliding wheel slows to at most standstill (the error never reverses the reading).
"""

from __future__ import annotations

import numpy as np

from devices.emulator.scenario import OdometerModel

RISE = 0.75
"""Share of a WSP cycle during which the error grows (the rest is the wheel's recovery)."""


def sawtooth(phase: np.ndarray) -> np.ndarray:
    """One cycle's shape at phase in [0, 1): 0 -> 1 over [0, RISE), back to 0 over the rest."""
    return np.where(phase < RISE, phase / RISE, (1.0 - phase) / (1.0 - RISE))


def _cycles(
    active: np.ndarray, t: np.ndarray, period: float, depth: float, jitter: float, u: np.ndarray
) -> np.ndarray:
    """Error magnitude (>= 0) of the WSP cycles over each stretch where ``active`` holds."""
    n = len(t)
    idx = np.arange(n)
    start = active & ~np.concatenate(([False], active[:-1]))
    first = np.maximum.accumulate(np.where(start, idx, 0))
    tau = t - t[first]
    k = np.floor(tau / period).astype(np.int64)
    cycle_depth = depth * (1.0 - jitter * u[np.minimum(first + k, n - 1)])
    return np.where(active, cycle_depth * sawtooth(tau / period - k), 0.0)


def wheel_error(
    od: OdometerModel,
    t: np.ndarray,
    accel_mps2: np.ndarray,
    speed_mps: np.ndarray,
    run_end_s: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Wheel speed minus train speed (m/s) at measurement times t (s, run time)."""
    err = np.zeros(len(t), dtype=np.float64)
    if not (od.slide_depth_mps or od.slip_depth_mps) or len(t) == 0:
        return err
    end = od.low_adhesion_end_s if od.low_adhesion_end_s is not None else run_end_s
    window = (t >= od.low_adhesion_start_s) & (t < end)
    sign = np.where(speed_mps < 0.0, -1.0, 1.0)
    along = sign * accel_mps2  # > 0 motoring, < 0 braking, whichever way the train runs
    moving = speed_mps != 0.0
    u_slide = rng.random(len(t))
    u_slip = rng.random(len(t))
    if od.slide_depth_mps:
        braking = window & moving & (along < -od.slide_min_decel_mps2)
        mag = _cycles(braking, t, od.slide_period_s, od.slide_depth_mps, od.wsp_jitter, u_slide)
        err -= sign * np.minimum(mag, np.abs(speed_mps))
    if od.slip_depth_mps:
        motoring = window & moving & (along > od.slip_min_accel_mps2)
        mag = _cycles(motoring, t, od.slip_period_s, od.slip_depth_mps, od.wsp_jitter, u_slip)
        err += sign * mag
    return err


def quantise_speed(speed_mps: np.ndarray, resolution_mps: float) -> np.ndarray:
    """The odometer's own speed step (a pulse count per gate time), then the wire's mm/s."""
    if resolution_mps > 0.0:
        speed_mps = np.rint(speed_mps / resolution_mps) * resolution_mps
    return np.clip(np.rint(speed_mps * 1000.0), -(2**31), 2**31 - 1).astype(np.int64)
