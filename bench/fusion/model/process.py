"""The motion and the track: f, its Jacobian F and the process noise Q over one step dt.

The train moves (v += a dt) and its acceleration changes by white jerk; the gradient
changes only with distance: S += K dx with dx = v dt, S and K taking noise per metre
travelled (an integrated random walk in x), so at standstill nothing about the track can
grow uncertain. The wheel-scale error wears per metre, the biases and the odometer's
latency walk in time, the body's static pitch only while the train stands (the load
moves at stations).
"""

from __future__ import annotations

import numpy as np

from bench.fusion.model._jit import jit
from bench.fusion.model.state import (
    B1,
    B2,
    B3,
    NX,
    P_QB,
    P_QE,
    P_QJ,
    P_QK,
    P_QL,
    P_QP,
    P_QS,
    P_RODO,
    A,
    E,
    K,
    L,
    P,
    S,
    V,
)  # fmt: skip


@jit
def f(x: np.ndarray, dt: float) -> np.ndarray:
    """The state after dt seconds (the bilinear K v term makes the model non-linear)."""
    out = x.copy()
    out[V] = x[V] + x[A] * dt
    out[S] = x[S] + x[K] * x[V] * dt
    return out


@jit
def jacobian(x: np.ndarray, dt: float) -> np.ndarray:
    """F = df/dx at x."""
    out = np.eye(NX)
    out[V, A] = dt
    out[S, K] = x[V] * dt
    out[S, V] = x[K] * dt
    return out


@jit
def noise(x: np.ndarray, dt: float, prm: np.ndarray) -> np.ndarray:
    """Q over dt: white jerk on (V, A); per metre on (S, K) and E; in time on the biases."""
    out = np.zeros((NX, NX))
    q = prm[P_QJ]
    out[V, V] = q * dt * dt * dt / 3.0
    out[V, A] = q * dt * dt / 2.0
    out[A, V] = out[V, A]
    out[A, A] = q * dt
    dx = x[V] * dt
    d = abs(dx)
    qk = prm[P_QK]
    out[S, S] = prm[P_QS] * d + qk * d * d * d / 3.0
    out[S, K] = qk * d * dx / 2.0
    out[K, S] = out[S, K]
    out[K, K] = qk * d
    out[E, E] = prm[P_QE] * d
    for b in (B1, B2, B3):
        out[b, b] = prm[P_QB] * dt
    out[L, L] = prm[P_QL] * dt
    if abs(x[V]) < prm[P_RODO]:  # standing (the odometer cannot tell it from 0): loading
        out[P, P] = prm[P_QP] * dt
    return out
