"""The forward pass over a recorded or live stream, block by block, and the smoother's pass.

The three channel readings are averaged over blocks of a fixed number of samples (at most
``block_s``); each block is one step of the model at its mid-time: predict there, apply the
SPEED_REF frames the block's samples apply (each at its own age), then the block's mean
readings. A block whose innovation is beyond the gate is tried without each channel in turn
(a spike or a drift is a large bias on one channel: the same likelihood test isolates it);
when no channel explains it, it is a step of acceleration and A's variance takes it.
"""

from __future__ import annotations

import sys

import numpy as np

from bench.fusion.kernel_cache import drop_stale
from bench.fusion.model import _jit, ekf, jump, linalg, measure, process, smoother, state
from bench.fusion.model._jit import jit
from bench.fusion.model.ekf import predict, update_full
from bench.fusion.model.state import NX, P_RCH, P_RODO, P_VTAU, A, E, V

ZUPT_SIGMA_MPS2 = 0.002
"""At standstill (the odometer reads exactly 0) a = 0 with this 1-sigma."""


@jit
def _rows(
    idx: list[int],
    ymean: np.ndarray,
    count: np.ndarray,
    hfull: np.ndarray,
    jfull: np.ndarray,
    rfull: np.ndarray,
    prm: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(z, h, H, R) of the channels idx: R of a block mean has the white noise of count
    samples (r / count), the vibration in full (it is not white over a block)."""
    m = len(idx)
    z, hx, jac, r = np.empty(m), np.empty(m), np.empty((m, NX)), np.empty((m, m))
    for a in range(m):
        z[a] = ymean[idx[a]]
        hx[a] = hfull[idx[a]]
        jac[a] = jfull[idx[a]]
        for b in range(m):
            r[a, b] = rfull[idx[a], idx[b]]
        r[a, a] += prm[P_RCH] * prm[P_RCH] * (1.0 / count[idx[a]] - 1.0)
    return z, hx, jac, r


@jit
def _channel_update(
    x: np.ndarray,
    cov: np.ndarray,
    ymean: np.ndarray,
    count: np.ndarray,
    cos_th: np.ndarray,
    sin_th: np.ndarray,
    prm: np.ndarray,
    gate: float,
    vib: np.ndarray,
    glr: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Update by the block's mean readings of the channels with count > 0 (vib: the body's
    vibration variances along and normal to the track), the update kept followed by the
    jump test's hypotheses (glr); returns the channel left out (0-2), -1 none, -2 the block
    taken as a step of acceleration."""
    hfull = measure.channels(x, cos_th, sin_th, prm)
    jfull = measure.channels_jacobian(x, cos_th, sin_th, prm)
    rfull = measure.channels_noise(cos_th, sin_th, prm, vib[0], vib[1])
    best = (x, cov, -1, np.zeros((0, NX)), np.zeros((0, 0)), np.zeros((0, 0)), np.zeros(0))
    best_nis = np.inf
    for drop in range(-1, 3):
        idx = [i for i in range(3) if count[i] > 0 and i != drop]
        if len(idx) < 2 or (drop >= 0 and count[drop] == 0):
            continue
        z, hx, jac, r = _rows(idx, ymean, count, hfull, jfull, rfull, prm)
        xn, pn, nis, gain, s_inv, nu = update_full(x, cov, z, hx, jac, r)
        if drop == -1 and nis <= gate:
            jump.follow(glr, jac, gain, s_inv, nu)
            return xn, pn, -1
        if nis < best_nis:
            best_nis, best = nis, (xn, pn, drop, jac, gain, s_inv, nu)
    if best_nis <= gate and best[2] >= 0:
        jump.follow(glr, best[3], best[4], best[5], best[6])
        return best[0], best[1], best[2]
    # no channel explains it: a step of acceleration (a notch): raise A's variance, again
    nu1 = ymean[1] - hfull[1] if count[1] > 0 else ymean[0] - hfull[0]
    cov2 = cov.copy()
    cov2[A, A] += nu1 * nu1
    idx = [i for i in range(3) if count[i] > 0]
    z, hx, jac, r = _rows(idx, ymean, count, hfull, jfull, rfull, prm)
    xn, pn, _, gain, s_inv, nu = update_full(x, cov2, z, hx, jac, r)
    jump.follow(glr, jac, gain, s_inv, nu)
    return xn, pn, -2


@jit
def _learn_vibration(
    vib: np.ndarray,
    x: np.ndarray,
    ymean: np.ndarray,
    count: np.ndarray,
    cos_th: np.ndarray,
    sin_th: np.ndarray,
    prm: np.ndarray,
    dt: float,
) -> None:
    """Learn the body's vibration (in place): the block's innovation of the three readings
    solved for its parts along and normal to the track by least squares, their squares
    less the channels' white noise averaged over vibration_tau_s."""
    nu = ymean - measure.channels(x, cos_th, sin_th, prm)
    a11 = a12 = a22 = b1 = b2 = 0.0
    for i in range(3):
        a11 += cos_th[i] * cos_th[i]
        a12 += cos_th[i] * sin_th[i]
        a22 += sin_th[i] * sin_th[i]
        b1 += cos_th[i] * nu[i]
        b2 += sin_th[i] * nu[i]
    det = a11 * a22 - a12 * a12
    if det <= 0.0:
        return
    eu = (a22 * b1 - a12 * b2) / det
    ew = (a11 * b2 - a12 * b1) / det
    white = prm[P_RCH] * prm[P_RCH] / count.min()
    w = min(max(dt, 0.0) / prm[P_VTAU], 1.0)
    vib[0] += w * (eu * eu - white * a22 / det - vib[0])
    vib[1] += w * (ew * ew - white * a11 / det - vib[1])


@jit
def forward(
    b: np.ndarray,
    y: np.ndarray,
    used: np.ndarray,
    fa: np.ndarray,
    fw: np.ndarray,
    fs: np.ndarray,
    fr: np.ndarray,
    fst: np.ndarray,
    accept: np.ndarray,
    cos_th: np.ndarray,
    sin_th: np.ndarray,
    prm: np.ndarray,
    x0: np.ndarray,
    p0: np.ndarray,
    block: int,
    odo_gate: float,
    ch_gate: float,
    vib: np.ndarray,
    glr: np.ndarray,
    t_prev0: float,
    first: bool,
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray
]:
    """b (N,) board time s; y (N, 3) readings m/s^2; used (N, 3) channel usable; frames
    (anchor sample, board time measured, speed m/s, restart, standstill, and whether it
    may be applied: a smoother's second pass leaves out the frames its first found
    slipping). Returns per block: mid-time, predicted x and P, filtered x and P, the
    Jacobian into the block, odometer rejects, and the vertical-curve jump found at the
    block (bench.fusion.model.jump): (K's step, its onset that many blocks before), (0, -1)
    for none; a jump's correction covariance is in the block's predicted P (the smoother
    takes it as process noise into the block).

    A stream goes on where the last call ended (bench.fusion.model.stream): x0, p0 the
    last block's filtered state, vib (2,) the body's vibration learnt so far and glr the
    jump test's onset hypotheses (both updated in place), t_prev0 the last block's
    mid-time; ``first`` for the stream's first block, which predicts from b[0] whatever
    its dt."""
    n = len(b)
    nb = (n + block - 1) // block
    t_mid = np.empty(nb)
    xp, pp = np.empty((nb, NX)), np.empty((nb, NX, NX))
    xf, pf = np.empty((nb, NX)), np.empty((nb, NX, NX))
    jac = np.zeros((nb, NX, NX))
    rejects = np.zeros(nb)
    jumps = np.zeros((nb, 2))
    jumps[:, 1] = -1.0
    x, cov = x0.copy(), p0.copy()
    t_prev = b[0] if first and n else t_prev0
    fi = 0
    ymean, count = np.zeros(3), np.zeros(3)
    h_zupt = np.zeros((1, NX))
    h_zupt[0, A] = 1.0
    r_zupt = np.empty((1, 1))
    r_zupt[0, 0] = ZUPT_SIGMA_MPS2 * ZUPT_SIGMA_MPS2
    for k in range(nb):
        lo, hi = k * block, min((k + 1) * block, n)
        tm = 0.5 * (b[lo] + b[hi - 1])
        dt = tm - t_prev
        if dt > 0.0 or (first and k == 0):
            fj = process.jacobian(x, dt, prm)
            q = process.noise(x, dt, prm)
            jump.propagate(glr, fj, abs(x[V]) * dt, tm, prm)
            x, cov = predict(process.f(x, dt, prm), fj, cov, q)
            jac[k] = fj
        else:
            jac[k] = np.eye(NX)
        t_prev = tm
        xp[k], pp[k] = x, cov
        t_mid[k] = tm
        # the frames the block's samples apply
        while fi < len(fa) and fa[fi] < hi:
            if not accept[fi] and not fr[fi]:
                rejects[k] += 1
                fi += 1
                continue
            delta = tm - fw[fi]
            z = np.empty(1)
            z[0] = fs[fi]
            if fr[fi]:
                # a restart (the first frame, or one after a gap): v from this frame
                x[V] = fs[fi] / (1.0 + x[E]) + delta * x[A]
                cov[V, :] = 0.0
                cov[:, V] = 0.0
                cov[V, V] = prm[P_RODO] * prm[P_RODO]
                jump.restart_speed(glr)
            hx = measure.odometer(x, delta)
            hj = measure.odometer_jacobian(x, delta)
            xn, pn, nis, gain, s_inv, nu = update_full(
                x, cov, z, hx, hj, measure.odometer_noise(prm)
            )
            if nis <= odo_gate:
                x, cov = xn, pn
                jump.follow(glr, hj, gain, s_inv, nu)
            else:
                rejects[k] += 1
            if fst[fi] and fs[fi] == 0.0:
                za = np.zeros(1)
                ha = np.zeros(1)
                ha[0] = x[A]
                x, cov, _, gain, s_inv, nu = update_full(x, cov, za, ha, h_zupt, r_zupt)
                jump.follow(glr, h_zupt, gain, s_inv, nu)
                hv = np.zeros((1, NX))
                hv[0, V] = 1.0
                zv = np.zeros(1)
                xv = np.zeros(1)
                xv[0] = x[V]
                x, cov, _, gain, s_inv, nu = update_full(x, cov, zv, xv, hv, r_zupt)
                jump.follow(glr, hv, gain, s_inv, nu)
            fi += 1
        ymean[:] = 0.0
        count[:] = 0.0
        for i in range(lo, hi):
            for c in range(3):
                if used[i, c]:
                    ymean[c] += y[i, c]
                    count[c] += 1.0
        if (count > 0).sum() >= 2:
            for c in range(3):
                if count[c] > 0:
                    ymean[c] /= count[c]
            if count.min() > 0:
                _learn_vibration(vib, x, ymean, count, cos_th, sin_th, prm, dt)
            x, cov, _ = _channel_update(
                x, cov, ymean, count, cos_th, sin_th, prm, ch_gate, vib, glr
            )
        x, cov, added, step, age = jump.test(glr, x, cov, tm, prm)
        if age >= 0.0:
            pp[k] += added  # the step as process noise into this block, for the smoother
            jumps[k, 0], jumps[k, 1] = step, age
        xf[k], pf[k] = x, cov
    return t_mid, xp, pp, xf, pf, jac, rejects, jumps


# forward freezes the code and constants (the state's slots) of every module of the model
# into its machine code: numba's cache must be dropped when any of them changed
drop_stale(
    forward, (sys.modules[__name__], _jit, linalg, ekf, jump, measure, process, state, smoother)
)
