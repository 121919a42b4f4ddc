"""The measurements: h, H = dh/dx and R for the odometer and for the raw channel readings.

The odometer reads (1 + E) times the speed it saw delta + L seconds ago (v - (delta + L) a
to first order; delta the age its clock mapping gives, L the latency beyond it). E is the
wheel-diameter error (a wheel configured 1 % small reads 1 % high); it is observable
whenever the speed changes while the accelerometers measure the acceleration that
changed it, and L whenever the acceleration is not zero.

Channel i, mounted at theta_i in the track's vertical plane, reads
y_i = cos(theta_i + P) u + sin(theta_i + P) w + b_i with u = a + S, the specific force along
the track, and w = c + v^2 K / c, c = sqrt(g^2 - S^2), normal to it; P + TB is the body's
pitch against the track (the board sits on the body): the load's and the acceleration's
(on a vertical curve of radius R the car is pressed down or lifted by v^2 / R, and
1/R = K / c).
"""

from __future__ import annotations

import math

import numpy as np

from bench.fusion.model._jit import jit
from bench.fusion.model.state import (
    B1,
    NX,
    P_G,
    P_RCH,
    P_RODO,
    P_RVU,
    P_RVW,
    TB,
    A,
    E,
    K,
    L,
    P,
    S,
    V,
)  # fmt: skip


@jit
def odometer(x: np.ndarray, delta: float) -> np.ndarray:
    """h: the SPEED_REF reading expected of x, measured delta s before x's instant."""
    out = np.empty(1)
    out[0] = (1.0 + x[E]) * (x[V] - (delta + x[L]) * x[A])
    return out


@jit
def odometer_jacobian(x: np.ndarray, delta: float) -> np.ndarray:
    """H = dh/dx of :func:`odometer`."""
    out = np.zeros((1, NX))
    scale = 1.0 + x[E]
    age = delta + x[L]
    out[0, V] = scale
    out[0, A] = -age * scale
    out[0, E] = x[V] - age * x[A]
    out[0, L] = -scale * x[A]
    return out


@jit
def odometer_noise(prm: np.ndarray) -> np.ndarray:
    """R of one SPEED_REF reading."""
    out = np.empty((1, 1))
    out[0, 0] = prm[P_RODO] * prm[P_RODO]
    return out


@jit
def channels(x: np.ndarray, cos_th: np.ndarray, sin_th: np.ndarray, prm: np.ndarray) -> np.ndarray:
    """h: the three raw channel readings (m/s^2) expected of x."""
    g = prm[P_G]
    u = x[A] + x[S]
    c = math.sqrt(g * g - x[S] * x[S])
    w = c + x[V] * x[V] * x[K] / c
    cp, sp = math.cos(x[P] + x[TB]), math.sin(x[P] + x[TB])
    out = np.empty(3)
    for i in range(3):
        ci = cos_th[i] * cp - sin_th[i] * sp  # cos(theta_i + P + TB)
        si = sin_th[i] * cp + cos_th[i] * sp  # sin(theta_i + P + TB)
        out[i] = ci * u + si * w + x[B1 + i]
    return out


@jit
def channels_jacobian(
    x: np.ndarray, cos_th: np.ndarray, sin_th: np.ndarray, prm: np.ndarray
) -> np.ndarray:
    """H = dh/dx of :func:`channels`."""
    g = prm[P_G]
    s, v, k = x[S], x[V], x[K]
    c = math.sqrt(g * g - s * s)
    u = x[A] + s
    w = c + v * v * k / c
    dw_ds = -s / c + v * v * k * s / (c * c * c)
    dw_dv = 2.0 * v * k / c
    dw_dk = v * v / c
    cp, sp = math.cos(x[P] + x[TB]), math.sin(x[P] + x[TB])
    out = np.zeros((3, NX))
    for i in range(3):
        ci = cos_th[i] * cp - sin_th[i] * sp
        si = sin_th[i] * cp + cos_th[i] * sp
        out[i, A] = ci
        out[i, S] = ci + si * dw_ds
        out[i, V] = si * dw_dv
        out[i, K] = si * dw_dk
        out[i, P] = -si * u + ci * w
        out[i, TB] = out[i, P]
        out[i, B1 + i] = 1.0
    return out


@jit
def channels_noise(
    cos_th: np.ndarray, sin_th: np.ndarray, prm: np.ndarray, vib_u2: float, vib_w2: float
) -> np.ndarray:
    """R of the three readings: each channel's own white noise plus the body's vibration
    (variances vib_u2 along the track and vib_w2 normal to it, m^2/s^4, at least the
    parameters' floors), which every channel sees through its mounting (so it is correlated
    between channels)."""
    r = prm[P_RCH] * prm[P_RCH]
    qu = max(vib_u2, prm[P_RVU] * prm[P_RVU])
    qw = max(vib_w2, prm[P_RVW] * prm[P_RVW])
    out = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            out[i, j] = cos_th[i] * cos_th[j] * qu + sin_th[i] * sin_th[j] * qw
        out[i, i] += r
    return out
