"""The joint filter's compiled kernel: speed, acceleration and gradient from u and SPEED_REF.

One sequential loop over a batch of samples (and the SPEED_REF frames they apply), compiled
by numba. Batch (replay) and streaming (live) both call this very function, with the state
carried between calls in small float64 arrays, so the results are the same bits however a
stream is cut: a Kalman filter is a recursion, and a recursion run by one machine code in
one order does not depend on where the calls start and stop. No fastmath: IEEE semantics.

State x: the slots of :mod:`bench.fusion.joint_layout` (v, a, s, k, l, b, z, zc; docs/ESTIMATOR.md).

Process over dt with d = |v| dt: v += a dt (+ white-jerk terms), s += k v dt; s and k
take process noise only per metre travelled, so a train at rest keeps its gradient.
Measurements: u = a + s at every sample (R from the channel noise and the subset's
(H^T H)^-1); odometer z = v - (delta + l) a at every applied SPEED_REF frame, gated by its
innovation (slip and slide); a = 0 and v = 0 at standstill (zero-velocity update); and the
mean of w over short blocks, w = g cos(alpha) + v^2/R + b with v^2/R = v^2 k / (g cos(alpha)):
on a vertical curve the car is pressed onto (or lifted off) its bogies, which tells k long
before the odometer can, so the gradient follows a curve instead of lagging it.
"""

from __future__ import annotations

import math
import sys

import numpy as np
from numba import njit

from bench.fusion import joint_drift, joint_layout, joint_rewind, joint_updates, joint_w
from bench.fusion.joint_layout import (
    C_SEQ,
    F_RESTART,
    F_SPEED,
    F_STILL,
    F_WHEN,
    FRING_N,
    H_B,
    H_F0,
    H_FN,
    H_LATCHED,
    H_MASK,
    H_RES,
    H_U,
    H_W,
    HIST_N,
    IA,
    IK,
    IL,
    IS,
    IV,
    M_BANK,
    M_HAVE_V,
    M_HAVE_Z,
    M_LAST_B,
    M_LAST_FRAME,
    M_LAST_SEEN,
    M_LAST_Z,
    M_NOISE2,
    M_NOISE_N,
    M_OK_SINCE,
    M_OUT_SINCE,
    M_QUANT,
    M_RESLOW,
    M_REWIND_T,
    M_ROUGH,
    M_RV,
    M_SNAP_T,
    M_STARTED,
    M_STEP_A0,
    M_STEP_T,
    M_STILL,
    M_STREAK_NU0,
    M_STREAK_T0,
    M_SUSPECT,
    M_UFAST,
    M_USTILL,
    M_USTILL_N,
    M_WPEND,
    M_WVAR,
    M_ZUPT_FROM,
    M_ZVAR,
    NX,
    P_BIAS,
    P_COAST,
    P_DRIFT_LLR,
    P_G,
    P_GATE,
    P_K0,
    P_KJUMP,
    P_KMAX,
    P_LAT_ACC,
    P_LIMIT,
    P_LSIG,
    P_NOISE_FLOOR,
    P_NOISE_TAU,
    P_RECOVER,
    P_RES_LIMIT,
    P_RESET,
    P_RESLOW_TAU,
    P_RV,
    P_RV_MAX,
    P_RV_TAU,
    P_RZ,
    P_SLIP,
    P_UFAST_TAU,
    P_UGATE,
    P_USE_W,
    P_USTILL_TAU,
    P_WRES_MAX,
    P_ZGATE,
    P_ZHOLD,
    S_SEQ,
    SNAP_EVERY_S,
)
from bench.fusion.joint_updates import _innov_var, _predict, _update, _update_motion
from bench.fusion.joint_w import _w_block
from bench.fusion.kernel_cache import drop_stale


@njit(cache=True)
def _restart_speed(x, cov, z, r):  # type: ignore[no-untyped-def]
    """Speed from the odometer (z, variance r), uncorrelated with the rest."""
    x[IV] = z
    for i in range(NX):
        cov[IV, i] = 0.0
        cov[i, IV] = 0.0
    cov[IV, IV] = r


@njit(cache=True, inline="always")
def _sample(  # type: ignore[no-untyped-def]
    x,
    cov,
    m,
    p,
    hist,
    fring,
    slot,
    ru_of_mask,
    rw_of_mask,
    excl_gain,
    excl_gain_w,
    gain_max,
    xb,
    cb,
    mb,
    h,
    ph,
    off,
    r3,
    out_grad,
    out_sigma,
    out_suspect,
    out_coast,
    out_accel,
    oi,
):
    """One sample (row ``slot`` of the input ring, its SPEED_REF frames in the frame ring)
    through the filter, in place on (x, cov, m) and the drift copies; outputs at ``oi``."""
    g = p[P_G]
    bi = hist[slot, H_B]
    mask_i = int(hist[slot, H_MASK])
    latched_i = int(hist[slot, H_LATCHED])
    res_in = hist[slot, H_RES]
    w_in = hist[slot, H_W]
    if m[M_STARTED] == 0.0:
        m[M_STARTED] = 1.0
        m[M_LAST_B] = bi
    dt = bi - m[M_LAST_B]
    if dt > 0.0:
        # without w nothing pins k: it walks as on the roughest ride (so too while the
        # channels disagree and w is not used: a drift would otherwise bend s through k)
        w_held = res_in == res_in and mask_i == 7 and (abs(m[M_RESLOW]) > p[P_WRES_MAX])
        rough = m[M_ROUGH] if (p[P_USE_W] != 0.0 and not w_held) else 1.0
        blind = not (bi - m[M_LAST_FRAME] <= p[P_COAST])
        _predict(x, cov, dt, p, blind, rough, m[M_ZVAR])
        if m[M_BANK] != 0.0:  # the copies use w: k walks as the ride allows
            rb = m[M_ROUGH] if p[P_USE_W] != 0.0 else 1.0
            joint_drift.predict(xb, cb, dt, p, blind, rb, m[M_ZVAR])
    m[M_LAST_B] = bi
    # -- channel noise from the parity residual (rigid-body motion does not show in it)
    r_i = res_in
    if r_i == r_i:
        # clipped at the residual limit: a spike must not pass for noise (or, below, for
        # a slow error), a slow drift stays below the limit until it is excluded
        lim = p[P_RES_LIMIT]
        r_i = -lim if r_i < -lim else lim if r_i > lim else r_i
        cnt = m[M_NOISE_N] + 1.0
        m[M_NOISE_N] = cnt
        alpha = 1.0 / cnt
        tau_alpha = dt / p[P_NOISE_TAU] if dt > 0.0 else 0.0
        if tau_alpha > alpha:
            alpha = tau_alpha
        if cnt == 1.0:
            m[M_NOISE2] = r_i * r_i
        else:
            m[M_NOISE2] += alpha * (r_i * r_i - m[M_NOISE2])
    # -- SPEED_REF frames that this sample applies
    f0 = int(hist[slot, H_F0])
    for qf in range(int(hist[slot, H_FN])):
        jf = (f0 + qf) % FRING_N
        z = fring[jf, F_SPEED]
        when = fring[jf, F_WHEN]
        m[M_LAST_SEEN] = when
        m[M_STILL] = fring[jf, F_STILL]
        # the odometer's resolution: the least non-zero step between two readings
        if m[M_HAVE_Z] != 0.0:
            step = abs(z - m[M_LAST_Z])
            if step > 0.0 and step < m[M_QUANT]:
                m[M_QUANT] = step
        m[M_LAST_Z] = z
        m[M_HAVE_Z] = 1.0
        quant = m[M_QUANT] if m[M_QUANT] < 1.0 else 0.0
        floor = p[P_RV]
        rv = m[M_RV] if m[M_RV] > floor else floor
        if fring[jf, F_RESTART] != 0.0 or m[M_HAVE_V] == 0.0:
            _restart_speed(x, cov, z, rv)
            m[M_BANK] = 0.0
            m[M_HAVE_V] = 1.0
            m[M_STREAK_T0] = math.nan
            m[M_LAST_FRAME] = when
            continue
        delta = bi - when
        lag = delta + x[IL]
        # v back at the reading's instant: v - lag a, unless an acceleration step came
        # after that instant; then the acceleration before the step holds up to it
        back = lag  # how far back the present acceleration reaches
        a_old = x[IA]  # the acceleration before that
        since = bi - m[M_STEP_T]
        if since < lag:
            back = since
            a_old = m[M_STEP_A0]
        for q in range(NX):
            h[q] = 0.0
        h[IV] = 1.0
        h[IA] = -back
        # the latency shows only in motion: near standstill the odometer's dead band
        # (it reads 0 until a whole quantum) would pass for latency
        moving = z != 0.0
        if p[P_LSIG] > 0.0 and moving and abs(a_old) > p[P_LAT_ACC]:
            h[IL] = -a_old
        nu = z - (x[IV] - back * x[IA] - (lag - back) * a_old)
        s_nu = _innov_var(cov, h, rv)
        # a reading one quantum off is what a coarse odometer does, not a slip; and the
        # latency is uncertain even while it is not being estimated
        s_gate = s_nu if h[IL] != 0.0 else s_nu + a_old * a_old * cov[IL, IL]
        reach = math.sqrt(p[P_GATE] * s_gate) + quant
        accepted = abs(nu) <= reach
        if accepted:
            if m[M_BANK] != 0.0:  # before the filter's update, which reuses ph
                for k in range(3):
                    lag_k = 0.0 if h[IL] != 0.0 else xb[k, IL]
                    off[k] = -(delta - back + lag_k) * a_old
                joint_drift.update_scalar(xb, cb, mb, h, ph, z, off, rv, m[M_SUSPECT] != 0.0)
            if m[M_SUSPECT] != 0.0:
                _update_motion(x, cov, h, nu, rv, ph)
            else:
                _update(x, cov, h, nu, rv, ph)
            m[M_LAST_FRAME] = when
            m[M_STREAK_T0] = math.nan
            if m[M_OK_SINCE] != m[M_OK_SINCE]:
                m[M_OK_SINCE] = when
            if m[M_SUSPECT] != 0.0 and when - m[M_OK_SINCE] >= p[P_RECOVER]:
                m[M_SUSPECT] = 0.0
        # odometer noise learnt from the accepted frames' innovations (vibration, coarse
        # quantisation)
        if moving and accepted:
            e2 = nu * nu - (s_nu - rv)
            m[M_RV] += (e2 - m[M_RV]) / p[P_RV_TAU]
            if m[M_RV] > p[P_RV_MAX]:
                m[M_RV] = p[P_RV_MAX]
        if not accepted:
            m[M_SUSPECT] = 1.0
            m[M_OK_SINCE] = math.nan
            t0 = m[M_STREAK_T0]
            if t0 != t0:
                m[M_STREAK_T0] = when
                m[M_STREAK_NU0] = nu
            else:
                span = when - t0
                if span >= p[P_RESET]:
                    slope = (nu - m[M_STREAK_NU0]) / span
                    if abs(slope) < p[P_SLIP]:
                        # a clean drift no slip explains: the model was wrong, the
                        # acceleration got what belonged to the gradient
                        x[IS] -= slope
                        if cov[IS, IS] < slope * slope:
                            cov[IS, IS] = slope * slope
                        cov[IK, IK] += p[P_KJUMP] * p[P_KJUMP]  # a curve's start or end
                        _restart_speed(x, cov, z, rv)
                        m[M_BANK] = 0.0
                        m[M_STREAK_T0] = math.nan
                        m[M_LAST_FRAME] = when
                    elif span >= 3.0 * p[P_RESET]:
                        # slipping for this long: take the odometer's speed, keep s
                        _restart_speed(x, cov, z, rv)
                        m[M_BANK] = 0.0
                        m[M_STREAK_T0] = math.nan
                        m[M_LAST_FRAME] = when
    coasting = not (bi - m[M_LAST_SEEN] <= p[P_COAST])
    if latched_i > 0:
        # an exclusion by the residual or a stuck code: the channel's error grew until
        # now and its slow part went into s. Its size is the residual's slow mean over
        # the channel's parity weight; its share of u, that times the u weight
        if m[M_BANK] != 0.0:
            # the copy that ran without this channel since the residual grew is what
            # the filter would have been had it been excluded then
            joint_drift.adopt(x, cov, m, xb, cb, latched_i - 1)
        else:
            leak = m[M_RESLOW] * excl_gain[latched_i - 1]
            x[IS] -= leak
            cov[IS, IS] += leak * leak
    if mask_i != 7:
        if m[M_OUT_SINCE] != m[M_OUT_SINCE]:
            m[M_OUT_SINCE] = bi
    elif m[M_OUT_SINCE] == m[M_OUT_SINCE]:
        # a channel readmitted after longer than the slow mean's memory: the isolation
        # found its residual healthy for its recovery time, and what the slow mean still
        # holds is the fault's tail, not an error of the three channels now in
        if bi - m[M_OUT_SINCE] >= p[P_RESLOW_TAU]:
            m[M_RESLOW] = 0.0
        m[M_OUT_SINCE] = math.nan
    if r_i == r_i and dt > 0.0:
        m[M_RESLOW] += dt / p[P_RESLOW_TAU] * (r_i - m[M_RESLOW])
    # -- specific force along the track: u = a + s
    ui = hist[slot, H_U]
    have_u = ui == ui
    # the parity residual speaks of the channels in u and w only while all three are
    all3 = r_i == r_i and mask_i == 7
    # -- which channel drifts (joint_drift): copies while the residual's slow mean
    # stands out, until it falls back or the isolation excludes a channel
    if all3 and p[P_DRIFT_LLR] > 0.0 and m[M_HAVE_V] != 0.0:
        slow_now = abs(m[M_RESLOW])
        if m[M_BANK] == 0.0 and slow_now > p[P_WRES_MAX]:
            joint_drift.start(x, cov, m, xb, cb, mb, excl_gain)
        elif m[M_BANK] != 0.0 and slow_now < 0.5 * p[P_WRES_MAX]:
            m[M_BANK] = 0.0
    bank = m[M_BANK] != 0.0 and all3 and have_u
    if have_u:
        noise2 = m[M_NOISE2] if m[M_NOISE2] > p[P_NOISE_FLOOR] else p[P_NOISE_FLOOR]
        r_u = noise2 * ru_of_mask[mask_i]
        stepped = False
        for q in range(NX):
            h[q] = 0.0
        h[IA] = 1.0
        h[IS] = 1.0
        nu_u = ui - (x[IA] + x[IS])
        if nu_u * nu_u > p[P_UGATE] * _innov_var(cov, h, r_u):
            # a step of acceleration (traction or brake notch): it is all acceleration,
            # the gradient cannot jump; without this a share of it would leak into s
            cov[IA, IA] += nu_u * nu_u
            if bi - m[M_STEP_T] > p[P_COAST]:  # a new step, not the same one again
                m[M_STEP_A0] = x[IA]  # before this step (not a sample into it)
            m[M_STEP_T] = bi
            stepped = True
        _update(x, cov, h, nu_u, r_u, ph)
        if bank:  # each copy on the two channels without its own
            for k in range(3):
                r3[k] = noise2 * ru_of_mask[7 ^ (1 << k)]
            joint_drift.update_u(xb, cb, h, ph, ui, res_in, excl_gain, r3, stepped)
            for k in range(3):
                r3[k] = noise2 * rw_of_mask[7 ^ (1 << k)]
            joint_drift.add_w(m, mb, p, h, ph, xb, cb, bi, w_in, res_in, excl_gain_w, r3, m[M_WVAR])
        # w only while the channels agree: a drifting channel bends w as a curve would
        if p[P_USE_W] != 0.0 and not (all3 and abs(m[M_RESLOW]) > p[P_WRES_MAX]):
            _w_block(x, cov, m, p, h, ph, bi, w_in, noise2 * rw_of_mask[mask_i])
        # -- zero-velocity update at standstill (odometer at 0 for standstill_s). Whether
        # the train still stands is judged by u against its own mean over the standstill,
        # not against s: a wrong s must not block the very update that puts it right
        fa = dt / p[P_UFAST_TAU] if dt > 0.0 else 0.0
        m[M_UFAST] += (fa if fa < 1.0 else 1.0) * (ui - m[M_UFAST])
        if m[M_STILL] != 0.0 and not coasting:
            n_still = m[M_USTILL_N]
            moved = n_still >= 20.0 and abs(m[M_UFAST] - m[M_USTILL]) > p[P_ZGATE]
            if moved:
                if bi >= m[M_ZUPT_FROM]:
                    # it started moving while the update held a at 0: the last samples
                    # went into s. The standstill's own mean of u is s (a was 0)
                    delta = m[M_USTILL] - x[IS]
                    x[IS] += delta
                    x[IA] -= delta
                    cov[IA, IA] += (m[M_UFAST] - m[M_USTILL]) ** 2
                m[M_ZUPT_FROM] = bi + p[P_ZHOLD]  # the accelerometers feel motion
                m[M_USTILL_N] = 0.0
            elif bi >= m[M_ZUPT_FROM]:
                for q in range(NX):
                    h[q] = 0.0
                h[IA] = 1.0
                _update(x, cov, h, -x[IA], p[P_RZ], ph)
                for q in range(NX):
                    h[q] = 0.0
                h[IV] = 1.0
                _update(x, cov, h, -x[IV], p[P_RV], ph)
                if bank:  # the copies at rest: v = 0 and a = 0 score them
                    off[0] = off[1] = off[2] = 0.0
                    joint_drift.update_scalar(xb, cb, mb, h, ph, 0.0, off, p[P_RV], False)
                    for q in range(NX):
                        h[q] = 0.0
                    h[IA] = 1.0
                    joint_drift.update_scalar(xb, cb, mb, h, ph, 0.0, off, p[P_RZ], False)
                m[M_HAVE_V] = 1.0
                # at rest nothing tells k (v^2/R = 0, no distance): it relaxes to its
                # prior (no curve) rather than keep what a rough ride left in it, so the
                # next start does not carry it into s
                if cov[IK, IK] < p[P_K0] * p[P_K0]:
                    relax = dt / p[P_USTILL_TAU] if dt > 0.0 else 0.0
                    x[IK] -= relax * x[IK]
                # the standstill's mean of u, from quiet samples only
                if n_still < 20.0 or abs(m[M_UFAST] - m[M_USTILL]) < 0.5 * p[P_ZGATE]:
                    n_still += 1.0
                    m[M_USTILL_N] = n_still
                    alpha = 1.0 / n_still
                    ta = dt / p[P_USTILL_TAU] if dt > 0.0 else 0.0
                    if ta > alpha:
                        alpha = ta
                    m[M_USTILL] += alpha * (ui - m[M_USTILL])
        else:
            m[M_USTILL_N] = 0.0
    # the states a line and an odometer can have: no sharper curve than the line's
    # sharpest, no negative or second-long latency
    kmax = p[P_KMAX]
    x[IK] = kmax if x[IK] > kmax else (-kmax if x[IK] < -kmax else x[IK])
    x[IL] = 0.0 if x[IL] < 0.0 else (1.0 if x[IL] > 1.0 else x[IL])
    # -- output: gradient = 1000 tan(asin(s/g)) and its 1-sigma
    lead = joint_drift.leader(m, mb, p) if all3 else -1
    s_est = x[IS] if lead < 0 else xb[lead, IS]
    var_s = cov[IS, IS] if lead < 0 else cb[lead, IS, IS]
    c2 = g * g - s_est * s_est
    if c2 > 0.0 and var_s >= 0.0:
        c = math.sqrt(c2)
        grad = 1000.0 * s_est / c
        # a slow parity residual means one channel is off by residual / parity weight
        # and u by that times its u weight; which channel is not known yet, so the
        # largest share counts until the isolation settles it
        # (once it stands out of its own noise: 4 sigma of a moving mean of white noise)
        slow = abs(m[M_RESLOW]) if (all3 and lead < 0) else 0.0
        if dt > 0.0 and slow * slow <= 16.0 * m[M_NOISE2] * dt / (2.0 * p[P_RESLOW_TAU]):
            slow = 0.0
        slow *= gain_max
        pend = m[M_WPEND]
        var = var_s + slow * slow + p[P_BIAS] * p[P_BIAS] + pend * pend
        sigma = 1000.0 * g * g / (c2 * c) * math.sqrt(var)
    else:
        grad = math.nan
        sigma = math.nan
    out_sigma[oi] = sigma
    out_grad[oi] = grad if (have_u and sigma <= p[P_LIMIT]) else math.nan
    out_suspect[oi] = m[M_SUSPECT] != 0.0
    out_coast[oi] = coasting
    out_accel[oi] = x[IA]


@njit(cache=True, nogil=True)  # the read-ahead and the writer run meanwhile
def run(  # type: ignore[no-untyped-def]
    x,
    cov,
    m,
    p,
    b,
    u,
    w,
    mask,
    residual,
    latched,
    ru_of_mask,
    rw_of_mask,
    excl_gain,
    excl_gain_w,
    xb,
    cb,
    mb,
    hist,
    fring,
    snaps,
    ctr,
    f_anchor,
    f_when,
    f_speed,
    f_restart,
    f_still,
    out_grad,
    out_sigma,
    out_suspect,
    out_coast,
    out_accel,
):
    """Run the filter over one batch, in place on (x, cov, m); outputs per sample.

    b: board time (s) per sample; u, w: specific force along and normal to the track (NaN
    without two channels); mask: channel-mask code per sample; residual: parity residual
    (NaN without three channels); latched: channel (1..3) whose exclusion by the residual or
    as stuck starts at this sample, else 0; ru_of_mask, rw_of_mask: (H^T H)^-1 uu and ww per
    mask code (inf below two channels); excl_gain: per channel, its u weight over its parity
    weight.
    Frames: anchor (sample index in this batch that first applies it, non-decreasing),
    board time it was measured, speed m/s, restart (after a long gap), standstill.
    hist, fring, snaps, ctr: the recent inputs and states kept for rewinding
    (:mod:`bench.fusion.joint_rewind`); every sample is recorded there first and filtered
    from there, so a replay runs exactly what the first pass ran.
    """
    n = len(b)
    nf = len(f_anchor)
    gain_max = 0.0
    for q in range(len(excl_gain)):
        if abs(excl_gain[q]) > gain_max:
            gain_max = abs(excl_gain[q])
    h = np.zeros(NX)
    ph = np.zeros(NX)
    off = np.zeros(3)  # the drift copies' scratch: offsets, R per copy
    r3 = np.zeros(3)
    j = 0
    for i in range(n):
        slot = joint_rewind.record(hist, ctr, b[i], u[i], w[i], mask[i], residual[i], latched[i])
        while j < nf and f_anchor[j] == i:
            joint_rewind.add_frame(
                hist, fring, ctr, slot, f_when[j], f_speed[j], f_restart[j], f_still[j]
            )
            j += 1
        # one call site (numba inlines it once): the sample, and after a rewind the replay
        # of every sample since the state it went back to, this one last (each replayed
        # sample writes this one's outputs; the last write is this sample's own)
        now = ctr[C_SEQ] - 1
        q = now
        replaying = False
        while True:
            _sample(
                x, cov, m, p, hist, fring, q % HIST_N, ru_of_mask, rw_of_mask, excl_gain,
                excl_gain_w, gain_max, xb, cb, mb, h, ph, off, r3,
                out_grad, out_sigma, out_suspect, out_coast, out_accel, i,
            )  # fmt: skip
            if not replaying and m[M_REWIND_T] == m[M_REWIND_T]:
                # the curve detector found a curve that began a while ago: back to the
                # state kept just before its start, k's variance raised there by its step
                q = int(snaps[joint_rewind.restore(snaps, ctr, m, x, cov, xb, cb, mb), S_SEQ])
                replaying = True
                continue
            if q == now:
                break
            if hist[q % HIST_N, H_B] - m[M_SNAP_T] >= SNAP_EVERY_S:
                joint_rewind.keep(snaps, hist, ctr, p, x, cov, m, xb, cb, mb, q)
            q += 1
        if b[i] - m[M_SNAP_T] >= SNAP_EVERY_S:
            joint_rewind.keep(snaps, hist, ctr, p, x, cov, m, xb, cb, mb, now)


# the loop freezes the code and constants of joint_w, joint_updates, joint_drift,
# joint_rewind and joint_layout into its own machine code: numba's cache must be dropped
# when any of them changed (kernel_cache)
drop_stale(
    run,
    (sys.modules[__name__], joint_w, joint_updates, joint_drift, joint_rewind, joint_layout),
)
