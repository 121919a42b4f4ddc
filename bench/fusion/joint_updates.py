"""The joint filter's scalar measurement updates, compiled by numba and shared by every
measurement of :mod:`bench.fusion.joint_kernel` and :mod:`bench.fusion.joint_w`: P h, the
innovation variance and the gain (P -= K (P h)^T, symmetrised) in one place and one order."""

from __future__ import annotations

from numba import njit

from bench.fusion.joint_layout import (
    IV,
    NX,
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
