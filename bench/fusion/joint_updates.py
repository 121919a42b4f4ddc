"""The joint filter's time update and scalar measurement updates, compiled by numba and
shared by :mod:`bench.fusion.joint_kernel`, :mod:`bench.fusion.joint_w` and
:mod:`bench.fusion.joint_drift`: the process model, P h, the innovation variance and the gain
(P -= K (P h)^T, symmetrised) in one place and one order."""

from __future__ import annotations

import math

from numba import njit

from bench.fusion.joint_layout import (
    IA,
    IB,
    IK,
    IL,
    IS,
    IV,
    IZ,
    NX,
    P_KVIS,
    P_LSIG,
    P_QA,
    P_QB,
    P_QK,
    P_QK_BLIND,
    P_QK_ROUGH,
    P_QL,
    P_QS,
    P_ZTAU,
)


@njit(cache=True)
def _project(cov, h, r, ph):  # type: ignore[no-untyped-def]
    """ph = P h (scratch of NX); returns the innovation variance h^T P h + r."""
    for i in range(NX):
        acc = 0.0
        for j in range(NX):
            acc += cov[i, j] * h[j]
        ph[i] = acc
    s = r
    for i in range(NX):
        s += h[i] * ph[i]
    return s


@njit(cache=True)
def _update(x, cov, h, nu, r, ph):  # type: ignore[no-untyped-def]
    """Scalar measurement update with row h (NX,), innovation nu and variance r (``ph``:
    scratch of NX). P -= K (P h)^T, then symmetrised. Returns the innovation variance."""
    s = _project(cov, h, r, ph)
    for i in range(NX):
        x[i] += ph[i] / s * nu
    for i in range(NX):
        ki = ph[i] / s
        for j in range(NX):
            cov[i, j] -= ki * ph[j]
    for i in range(NX):
        for j in range(i + 1, NX):
            mean = 0.5 * (cov[i, j] + cov[j, i])
            cov[i, j] = mean
            cov[j, i] = mean
    return s


@njit(cache=True)
def _update_motion(x, cov, h, nu, r, ph):  # type: ignore[no-untyped-def]
    """Scalar update of v alone (Schmidt: every other state is considered, not updated): a
    suspect odometer may still hold the speed, but neither the acceleration it would bend
    (and u would then pass the bend on to s) nor the gradient. P_vv and P_v. get the
    update, the rest of P stays."""
    s = _project(cov, h, r, ph)
    kv = ph[IV] / s
    x[IV] += kv * nu
    for j in range(NX):
        cov[IV, j] -= kv * ph[j]
    for j in range(NX):
        if j != IV:
            cov[j, IV] = cov[IV, j]
    return s


@njit(cache=True)
def _innov_var(cov, h, r):  # type: ignore[no-untyped-def]
    s = r
    for i in range(NX):
        acc = 0.0
        for j in range(NX):
            acc += cov[i, j] * h[j]
        s += h[i] * acc
    return s


@njit(cache=True)
def _predict(x, cov, dt, p, blind, rough, zvar):  # type: ignore[no-untyped-def]
    """x, P over dt seconds. EKF: s += k v dt is bilinear; F = I + dt (e_v e_a^T + k e_s e_v^T
    + v e_s e_k^T), applied to P's rows then columns in place (row s before row v, which
    it reads; likewise the columns). ``blind``: no odometer frame is being accepted, so
    the vertical-curve detector cannot see a curve start: k's process noise per metre is
    then the one that covers such jumps (P_QK_BLIND). ``rough`` (0..1): how much the body's
    vibration drowns w. On a smooth ride w pins k at once, so k may walk freely (P_QK) and
    the filter settles quickly; on a rough one w cannot, and a free k would only blur s:
    k then walks slowly (P_QK_ROUGH, log-interpolated) and the curve detector, whose
    pending decisions widen the output's sigma, follows the curves."""
    v, k = x[IV], x[IK]
    kdt, vdt = k * dt, v * dt
    x[IV] = v + x[IA] * dt
    x[IS] = x[IS] + k * v * dt
    for j in range(NX):  # rows: P <- F P
        cov[IS, j] = cov[IS, j] + kdt * cov[IV, j] + vdt * cov[IK, j]
        cov[IV, j] = cov[IV, j] + dt * cov[IA, j]
    for i in range(NX):  # columns: P <- P F^T
        cov[i, IS] = cov[i, IS] + kdt * cov[i, IV] + vdt * cov[i, IK]
        cov[i, IV] = cov[i, IV] + dt * cov[i, IA]
    qa = p[P_QA]
    cov[IV, IV] += qa * dt * dt * dt / 3.0
    cov[IV, IA] += qa * dt * dt / 2.0
    cov[IA, IV] += qa * dt * dt / 2.0
    cov[IA, IA] += qa * dt
    d = abs(v) * dt  # metres travelled: the gradient changes only with distance
    if d > 0.0:
        qs = p[P_QS]
        qr = p[P_QK_ROUGH]
        vis = p[P_KVIS]
        if vis > abs(v):
            # below this speed the curve detector misses curves (their v^2/R under its
            # threshold, which grows as 1/v^2): k's walk on a rough ride must hold them, its
            # variance as (vis / v)^4, at most the smooth ride's (v != 0: d > 0)
            qr *= (vis / abs(v)) ** 4
            qr = p[P_QK] if qr > p[P_QK] else qr
        qk = p[P_QK_BLIND] if blind else p[P_QK] * (qr / p[P_QK]) ** rough
        cov[IS, IS] += qs * d + qk * d * d * d / 3.0
        cov[IS, IK] += qk * d * d / 2.0
        cov[IK, IS] += qk * d * d / 2.0
        cov[IK, IK] += qk * d
    if p[P_LSIG] > 0.0:
        cov[IL, IL] += p[P_QL] * dt
    cov[IB, IB] += p[P_QB] * dt
    if p[P_ZTAU] > 0.0:
        # the body's vertical velocity: Gauss-Markov of stationary variance zvar
        e = math.exp(-dt / p[P_ZTAU])
        x[IZ] *= e
        for j in range(NX):
            cov[IZ, j] *= e
        for i in range(NX):
            cov[i, IZ] *= e
        cov[IZ, IZ] += zvar * (1.0 - e * e)
