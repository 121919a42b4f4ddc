"""The motion and the track: f, its Jacobian F and the process noise Q over one step dt.

The train moves (v += a dt) and its acceleration changes by white jerk; the gradient
changes only with distance: S += K dx with dx = v dt, S and K taking noise per metre
travelled (an integrated random walk in x), so at standstill nothing about the track can
grow uncertain. The wheel-scale error wears per metre, the biases and the odometer's
latency walk in time, the body's static pitch only while the train stands (the load
moves at stations).

The body pitches on its secondary suspension under acceleration: TB is the second-order
response (natural frequency wn, damping ratio zeta, unit gain at DC) to C a,

    TB'' + 2 zeta wn TB' + wn^2 TB = wn^2 C a,

as the emulator's devices/emulator/body_pitch.py has it. Over a step A is constant (white
jerk only changes it between steps), so the step is exact: (TB, TW) - (C a, 0) decays by
the transition matrix Phi of the free oscillator, e^(M dt), M = [[0, 1], [-wn^2, -2 zeta wn]].
C is a constant of the car (no noise: it is learnt, not tracked).
"""

from __future__ import annotations

import math

import numpy as np

from bench.fusion.model._jit import jit
from bench.fusion.model.state import (
    B1,
    B2,
    B3,
    NX,
    P_PF,
    P_PZ,
    P_QB,
    P_QE,
    P_QJ,
    P_QK,
    P_QL,
    P_QP,
    P_QS,
    P_RODO,
    TB,
    TW,
    A,
    C,
    E,
    K,
    L,
    P,
    S,
    V,
)  # fmt: skip


@jit
def pitch_transition(dt: float, prm: np.ndarray) -> tuple[float, float, float, float]:
    """Phi = e^(M dt) of the free body pitch (rows TB, TW): (phi11, phi12, phi21, phi22)."""
    wn = 2.0 * math.pi * prm[P_PF]
    sig = prm[P_PZ] * wn
    wd = wn * math.sqrt(1.0 - prm[P_PZ] * prm[P_PZ])
    e = math.exp(-sig * dt)
    co, si = math.cos(wd * dt), math.sin(wd * dt)
    return (
        e * (co + sig / wd * si),
        e * si / wd,
        -e * wn * wn / wd * si,
        e * (co - sig / wd * si),
    )


@jit
def f(x: np.ndarray, dt: float, prm: np.ndarray) -> np.ndarray:
    """The state after dt seconds (the bilinear K v and C a terms make it non-linear)."""
    out = x.copy()
    out[V] = x[V] + x[A] * dt
    out[S] = x[S] + x[K] * x[V] * dt
    p11, p12, p21, p22 = pitch_transition(dt, prm)
    settle = x[C] * x[A]  # the pitch the body settles to
    out[TB] = settle + p11 * (x[TB] - settle) + p12 * x[TW]
    out[TW] = p21 * (x[TB] - settle) + p22 * x[TW]
    return out


@jit
def jacobian(x: np.ndarray, dt: float, prm: np.ndarray) -> np.ndarray:
    """F = df/dx at x."""
    out = np.eye(NX)
    out[V, A] = dt
    out[S, K] = x[V] * dt
    out[S, V] = x[K] * dt
    p11, p12, p21, p22 = pitch_transition(dt, prm)
    out[TB, TB], out[TB, TW], out[TW, TB], out[TW, TW] = p11, p12, p21, p22
    out[TB, C] = (1.0 - p11) * x[A]
    out[TB, A] = (1.0 - p11) * x[C]
    out[TW, C] = -p21 * x[A]
    out[TW, A] = -p21 * x[C]
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
