"""Which channel drifts: three copies of the joint filter, each without one channel.

A slow drift of one channel shows in the parity residual long before the isolation's alarm
(whose limit must not fire on noise), but the residual cannot tell which channel it is: an
error on any of the three moves it. Until the isolation knows, the filter's u carries the
drift, its s takes a share of it, and the output's sigma has to cover the worst case (the
channel with the largest share of u).

The filter's own prediction can tell them apart. While the residual's slow mean stands out,
three copies run beside the filter, copy k on the two channels other than k: its u and w are
the filter's minus channel k's share of the residual (u - g_k r, exactly the two-channel
least-squares solution). The copy without the drifting channel sees a straight, steady line,
and the odometer and the zero-velocity update agree with it; the other two see a u that
drifts while their w says the line does not bend, so the odometer and w contradict them.
Their log-likelihoods (odometer, standstill and w innovations; not u, whose two-channel
noise differs from copy to copy while the drift goes into a) name the copy to trust once
it leads by P_DRIFT_LLR. The output then takes that copy's s and sigma; when the isolation
excludes a channel, the filter continues from that channel's copy instead of subtracting an
estimate of the leak. Compiled by numba; called from :func:`bench.fusion.joint_kernel.run`.
"""

from __future__ import annotations

import math

from numba import njit

from bench.fusion.joint_layout import (
    IA,
    IB,
    IK,
    IS,
    IV,
    M_BANK,
    M_BANK_WT0,
    M_RESLOW,
    MB_LL,
    MB_WCOUNT,
    MB_WFLOOR,
    MB_WSUM,
    NX,
    P_DRIFT_LLR,
    P_G,
    P_WBLOCK,
    P_WCORR,
)
from bench.fusion.joint_updates import _predict, _update, _update_motion


@njit(cache=True)
def start(x, cov, m, xb, cb, mb, gain_u):  # type: ignore[no-untyped-def]
    """Start the copies from the filter, each with the share of the drift so far that its
    hypothesis puts into s taken out (the leak the isolation's exclusion would take out)."""
    slow = m[M_RESLOW]
    for k in range(3):
        for i in range(NX):
            xb[k, i] = x[i]
            for j in range(NX):
                cb[k, i, j] = cov[i, j]
        leak = slow * gain_u[k]
        xb[k, IS] -= leak
        cb[k, IS, IS] += leak * leak
        mb[k, MB_LL] = 0.0
        mb[k, MB_WSUM] = 0.0
        mb[k, MB_WCOUNT] = 0.0
        mb[k, MB_WFLOOR] = 0.0
    m[M_BANK] = 1.0
    m[M_BANK_WT0] = math.nan


@njit(cache=True)
def predict(xb, cb, dt, p, blind, rough, zvar):  # type: ignore[no-untyped-def]
    for k in range(3):
        _predict(xb[k], cb[k], dt, p, blind, rough, zvar)


@njit(cache=True)
def update_u(xb, cb, h, ph, ui, ri, gain_u, r_u, stepped):  # type: ignore[no-untyped-def]
    """u = a + s for each copy, from its two channels; an acceleration step the filter saw
    (``stepped``) is one for the copies too."""
    for q in range(NX):
        h[q] = 0.0
    h[IA] = 1.0
    h[IS] = 1.0
    for k in range(3):
        nu = ui - gain_u[k] * ri - (xb[k, IA] + xb[k, IS])
        if stepped:
            cb[k, IA, IA] += nu * nu
        _update(xb[k], cb[k], h, nu, r_u[k], ph)


@njit(cache=True)
def update_scalar(xb, cb, mb, h, ph, z, offsets, r, motion_only):  # type: ignore[no-untyped-def]
    """One scalar measurement z = h x + offsets[k] for every copy, scored."""
    for k in range(3):
        pred = offsets[k]
        for i in range(NX):
            pred += h[i] * xb[k, i]
        nu = z - pred
        if motion_only:
            s = _update_motion(xb[k], cb[k], h, nu, r, ph)
        else:
            s = _update(xb[k], cb[k], h, nu, r, ph)
        if s > 0.0:
            mb[k, MB_LL] -= 0.5 * nu * nu / s


@njit(cache=True)
def add_w(m, mb, p, h, ph, xb, cb, bi, wi, ri, gain_w, r_white, w_var):  # type: ignore[no-untyped-def]
    """Block means of each copy's w (the filter's blocks, same length); at a block's end,
    h(x) = c + v^2 k / c + b as the filter's w measurement, R the filter's learnt block
    variance (floored at the copy's white noise), scored."""
    if m[M_BANK_WT0] != m[M_BANK_WT0]:
        m[M_BANK_WT0] = bi
        for k in range(3):
            mb[k, MB_WSUM] = 0.0
            mb[k, MB_WCOUNT] = 0.0
            mb[k, MB_WFLOOR] = 0.0
    for k in range(3):
        mb[k, MB_WSUM] += wi - gain_w[k] * ri
        mb[k, MB_WCOUNT] += 1.0
        mb[k, MB_WFLOOR] += r_white[k]
    if bi - m[M_BANK_WT0] < p[P_WBLOCK]:
        return
    m[M_BANK_WT0] = math.nan
    g = p[P_G]
    for k in range(3):
        cnt = mb[k, MB_WCOUNT]
        mean = mb[k, MB_WSUM] / cnt
        floor = mb[k, MB_WFLOOR] / (cnt * cnt)
        v, s, kk = xb[k, IV], xb[k, IS], xb[k, IK]
        c2 = g * g - s * s
        if c2 <= 0.0:
            continue
        c = math.sqrt(c2)
        for q in range(NX):
            h[q] = 0.0
        h[IV] = 2.0 * v * kk / c
        h[IS] = -s / c + v * v * kk * s / (c2 * c)
        h[IK] = v * v / c
        h[IB] = 1.0
        nu = mean - (c + v * v * kk / c + xb[k, IB])
        r = w_var if w_var > floor else floor
        span = cnt * (p[P_WBLOCK] / (cnt - 1.0)) if cnt > 1.0 else p[P_WBLOCK]
        if p[P_WCORR] > span:
            r = floor + (r - floor) * (p[P_WCORR] / span)
        _update(xb[k], cb[k], h, nu, r, ph)


@njit(cache=True)
def leader(m, mb, p):  # type: ignore[no-untyped-def]
    """The copy (0..2) that leads the other two by P_DRIFT_LLR in log-likelihood, or -1."""
    if m[M_BANK] == 0.0:
        return -1
    best, second, arg = -math.inf, -math.inf, -1
    for k in range(3):
        ll = mb[k, MB_LL]
        if ll > best:
            second = best
            best = ll
            arg = k
        elif ll > second:
            second = ll
    return arg if best - second >= p[P_DRIFT_LLR] else -1


@njit(cache=True)
def adopt(x, cov, m, xb, cb, k):  # type: ignore[no-untyped-def]
    """The filter continues from copy k (the channel the isolation excluded); the copies stop."""
    for i in range(NX):
        x[i] = xb[k, i]
        for j in range(NX):
            cov[i, j] = cb[k, i, j]
    m[M_BANK] = 0.0
