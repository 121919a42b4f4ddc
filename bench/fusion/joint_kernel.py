"""The joint filter's compiled kernel: speed, acceleration and gradient from u and SPEED_REF.

One sequential loop over a batch of samples (and the SPEED_REF frames they apply), compiled
by numba. Batch (replay) and streaming (live) both call this very function, with the state
carried between calls in small float64 arrays, so the results are the same bits however a
stream is cut: a Kalman filter is a recursion, and a recursion run by one machine code in
one order does not depend on where the calls start and stop. No fastmath: IEEE semantics.

State x: the slots of :mod:`bench.fusion.joint_layout` (v, a, s, k, l, b; docs/ESTIMATOR.md).

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

import numpy as np
from numba import njit

from bench.fusion.joint_layout import (
    IA,
    IB,
    IK,
    IL,
    IS,
    IV,
    M_HAVE_V,
    M_HAVE_Z,
    M_LAST_B,
    M_LAST_FRAME,
    M_LAST_SEEN,
    M_LAST_Z,
    M_NOISE2,
    M_NOISE_N,
    M_NOTCH_IN,
    M_NOTCH_OUT,
    M_NOTCH_POW,
    M_NOTCH_TH,
    M_NOTCH_X1,
    M_NOTCH_X2,
    M_OK_SINCE,
    M_QUANT,
    M_RESLOW,
    M_ROUGH,
    M_RV,
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
    M_WCOUNT,
    M_WE,
    M_WE1,
    M_WEVAR,
    M_WFLOOR,
    M_WHOLD,
    M_WPEND,
    M_WSUM,
    M_WT0,
    M_WVAR,
    M_ZUPT_FROM,
    NX,
    P_BIAS,
    P_COAST,
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
    P_NOTCH_MU,
    P_NOTCH_RHO,
    P_QA,
    P_QB,
    P_QK,
    P_QK_BLIND,
    P_QK_ROUGH,
    P_QL,
    P_QS,
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
    P_WBLOCK,
    P_WCORR,
    P_WDET_MIN,
    P_WDET_SIGMA,
    P_WDET_TAU,
    P_WDET_VAR_TAU,
    P_WGATE,
    P_WRES_MAX,
    P_WROUGH,
    P_WVAR_TAU,
    P_ZGATE,
    P_ZHOLD,
)

W_SIGMA_S_MAX = 0.02  # m/s^2: w is used once s is known this well (2 permil)


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
def _predict(x, cov, dt, p, blind, rough):  # type: ignore[no-untyped-def]
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
        qk = p[P_QK_BLIND] if blind else p[P_QK] * (p[P_QK_ROUGH] / p[P_QK]) ** rough
        cov[IS, IS] += qs * d + qk * d * d * d / 3.0
        cov[IS, IK] += qk * d * d / 2.0
        cov[IK, IS] += qk * d * d / 2.0
        cov[IK, IK] += qk * d
    if p[P_LSIG] > 0.0:
        cov[IL, IL] += p[P_QL] * dt
    cov[IB, IB] += p[P_QB] * dt


@njit(cache=True)
def _restart_speed(x, cov, z, r):  # type: ignore[no-untyped-def]
    """Speed from the odometer (z, variance r), uncorrelated with the rest."""
    x[IV] = z
    for i in range(NX):
        cov[IV, i] = 0.0
        cov[i, IV] = 0.0
    cov[IV, IV] = r


@njit(cache=True)
def _step_age(e1, e):  # type: ignore[no-untyped-def]
    """How long ago (in detector time constants) a step began, from the two cascaded moving
    means it drove: e1 = D (1 - exp(-x)), e = D (1 - exp(-x) (1 + x)); e / e1 rises from 0
    to 1 with x, so a bisection on it finds x. 0 when they disagree in sign."""
    if e1 == 0.0 or e / e1 <= 0.0:
        return 0.0
    r = e / e1
    if r >= 0.999:
        return 20.0
    lo, hi = 0.0, 20.0
    for _ in range(40):
        x = 0.5 * (lo + hi)
        q = math.exp(-x)
        if (1.0 - q * (1.0 + x)) / (1.0 - q) < r:
            lo = x
        else:
            hi = x
    return 0.5 * (lo + hi)


@njit(cache=True)
def _curve_detector(x, cov, m, p, nu, hk, bi, span):  # type: ignore[no-untyped-def]
    """A vertical curve's start or end under vibration: the block innovations' moving mean
    departs from zero by more than its own learnt spread. k then jumps by what explains it,
    and s has been moving by that k for about the detector's time constant: both get the
    matching (correlated) covariance, so the next updates can put right what was missed."""
    tau = p[P_WDET_TAU]
    alpha = span / tau if span < tau else 1.0
    # two moving means in cascade: the body's bounce (a few Hz) falls off as f^-2, so a
    # step of v^2/R stands out of a rough ride within about 2 tau
    e1 = m[M_WE1] + alpha * (nu - m[M_WE1])
    m[M_WE1] = e1
    e = m[M_WE] + alpha * (e1 - m[M_WE])
    m[M_WE] = e
    var = m[M_WEVAR]
    big = e * e > p[P_WDET_SIGMA] * p[P_WDET_SIGMA] * var and abs(e) > p[P_WDET_MIN]
    # half way to firing: a curve may have started, and s has been moving by its k since;
    # the output's sigma says so until the detector decides (the state is not touched)
    half = 4.0 * e * e > p[P_WDET_SIGMA] * p[P_WDET_SIGMA] * var and 2.0 * abs(e) > p[P_WDET_MIN]
    # the step the two means imply, and when it began
    age = _step_age(e1, e)
    step = e1 / (1.0 - math.exp(-age)) if age > 0.0 else e1
    m[M_WPEND] = abs(step / hk) * abs(x[IV]) * age * tau if (half and hk != 0.0) else 0.0
    if big and bi >= m[M_WHOLD] and hk * p[P_KMAX] > abs(e):
        dk = step / hk
        kmax = p[P_KMAX]
        dk = kmax if dk > kmax else (-kmax if dk < -kmax else dk)
        ds = dk * x[IV] * age * tau
        for i in range(NX):
            di = dk if i == IK else (ds if i == IS else 0.0)
            if di == 0.0:
                continue
            for j in range(NX):
                dj = dk if j == IK else (ds if j == IS else 0.0)
                cov[i, j] += di * dj
        m[M_WE] = 0.0
        m[M_WE1] = 0.0
        m[M_WPEND] = 0.0
        m[M_WHOLD] = bi + 2.0 * tau
    elif not big:
        # learnt from what is not a curve: a curve under the threshold (its end, after the
        # start fired) must not widen the spread the next one is judged by
        e2 = e * e
        quiet = p[P_WDET_MIN] / p[P_WDET_SIGMA]
        if var > quiet * quiet and e2 > 4.0 * var:
            e2 = 4.0 * var
        beta = span / p[P_WDET_VAR_TAU]
        m[M_WEVAR] = var + beta * (e2 - var)


@njit(cache=True)
def _notch(m, p, nu):  # type: ignore[no-untyped-def]
    """The block innovation with the body's bounce taken out: an adaptive notch (poles at
    radius rho, zeros on the unit circle at the frequency it learns) whose DC gain is 1,
    so a vertical curve's step in w passes whole while the bounce's tone does not."""
    rho = p[P_NOTCH_RHO]
    th = m[M_NOTCH_TH]
    if th != th:
        th = 0.0  # a quarter of the block rate until it learns the tone
        m[M_NOTCH_X1] = 0.0
        m[M_NOTCH_X2] = 0.0
        m[M_NOTCH_POW] = 0.0
    x1, x2 = m[M_NOTCH_X1], m[M_NOTCH_X2]
    xn = nu + 2.0 * rho * th * x1 - rho * rho * x2
    out = xn - 2.0 * th * x1 + x2
    dc = (2.0 - 2.0 * th) / (1.0 - 2.0 * rho * th + rho * rho)
    pw = m[M_NOTCH_POW] + 0.05 * (x1 * x1 - m[M_NOTCH_POW])
    if pw > 0.0:
        th += p[P_NOTCH_MU] * out * x1 / pw
        th = 0.98 if th > 0.98 else (-0.98 if th < -0.98 else th)
    m[M_NOTCH_TH], m[M_NOTCH_POW] = th, pw
    m[M_NOTCH_X1], m[M_NOTCH_X2] = xn, x1
    out /= dc
    # only a tone is taken out: where the notch removes little (a smooth ride, no bounce),
    # the innovation passes as it is, so a curve's step in w does not ring through it
    m[M_NOTCH_IN] += 0.025 * (nu * nu - m[M_NOTCH_IN])
    m[M_NOTCH_OUT] += 0.025 * (out * out - m[M_NOTCH_OUT])
    ratio = m[M_NOTCH_IN] / m[M_NOTCH_OUT] if m[M_NOTCH_OUT] > 0.0 else 0.0
    share = 0.5 * (ratio - 2.0)
    share = 0.0 if share < 0.0 else (1.0 if share > 1.0 else share)
    return nu + share * (out - nu)


@njit(cache=True)
def _w_block(x, cov, m, p, h, ph, bi, wi, r_white):  # type: ignore[no-untyped-def]
    """Add sample w to the current block; at the block's end apply its mean.

    h(x) = c + v^2 k / c + b with c = sqrt(g^2 - s^2): the normal specific force on a
    vertical curve (1/R = d alpha/dx, k = ds/dx = c / R). The block mean's noise is the car
    body's vertical vibration more than the sensors' white noise; its variance is learnt
    from the block innovations (floored at the white noise's share), so a rough ride widens
    it instead of bending k."""
    if m[M_WT0] != m[M_WT0]:
        m[M_WT0] = bi
        m[M_WSUM] = 0.0
        m[M_WCOUNT] = 0.0
        m[M_WFLOOR] = 0.0
    m[M_WSUM] += wi
    m[M_WCOUNT] += 1.0
    m[M_WFLOOR] += r_white
    if bi - m[M_WT0] < p[P_WBLOCK]:
        return
    cnt = m[M_WCOUNT]
    mean = m[M_WSUM] / cnt
    floor = m[M_WFLOOR] / (cnt * cnt)
    m[M_WT0] = math.nan
    if cov[IS, IS] > W_SIGMA_S_MAX * W_SIGMA_S_MAX:
        # s not known yet (a start in motion): c = sqrt(g^2 - s^2) at a guessed s would put
        # the guess's cos error into b for good; w waits until u and the odometer tell s
        return
    g = p[P_G]
    v, s, k = x[IV], x[IS], x[IK]
    c2 = g * g - s * s
    if c2 <= 0.0:
        return
    c = math.sqrt(c2)
    for q in range(NX):
        h[q] = 0.0
    h[IV] = 2.0 * v * k / c
    h[IS] = -s / c + v * v * k * s / (c2 * c)
    h[IK] = v * v / c
    h[IB] = 1.0
    nu = mean - (c + v * v * k / c + x[IB])
    if p[P_NOTCH_RHO] > 0.0:
        nu = _notch(m, p, nu)
    hph = _innov_var(cov, h, 0.0)
    e2 = nu * nu - hph
    r = m[M_WVAR] if m[M_WVAR] > floor else floor
    # the sensors' white noise is independent from block to block, the body's vibration
    # (what the learnt variance has beyond it) is not within its correlation time
    span = cnt * (p[P_WBLOCK] / (cnt - 1.0)) if cnt > 1.0 else p[P_WBLOCK]
    if p[P_WCORR] > span:
        r = floor + (r - floor) * (p[P_WCORR] / span)
    s_nu = hph + r
    _curve_detector(x, cov, m, p, nu, h[IK], bi, span)
    if nu * nu > p[P_WGATE] * s_nu and h[IK] * p[P_KMAX] > math.sqrt(p[P_WGATE] * s_nu):
        # a vertical curve starts or ends: k jumps, which its random walk per metre cannot
        # follow; the block tells by how much (at most the sharpest curve a line has), when
        # the train is fast enough for the curve to show at all
        dk = nu / h[IK]
        dk = p[P_KMAX] if dk > p[P_KMAX] else (-p[P_KMAX] if dk < -p[P_KMAX] else dk)
        # and s has moved by the old k for the part of the block after the jump: both get
        # the matching (correlated) variance, so this block's update puts both right
        ds = dk * x[IV] * span
        cov[IK, IK] += dk * dk
        cov[IK, IS] += dk * ds
        cov[IS, IK] += dk * ds
        cov[IS, IS] += ds * ds
    _update(x, cov, h, nu, r, ph)
    lim = p[P_WGATE] * s_nu
    e2 = lim if e2 > lim else (0.0 if e2 < 0.0 else e2)
    m[M_WVAR] += (e2 - m[M_WVAR]) / p[P_WVAR_TAU]
    # rough: the blocks' learnt spread on an absolute scale (a quiet w, however low its
    # noise, is smooth; a few hundredths of m/s^2 hide the start of a curve)
    rough = math.sqrt(m[M_WVAR]) / p[P_WROUGH] if m[M_WVAR] > 0.0 else 0.0
    m[M_ROUGH] = 1.0 if rough > 1.0 else rough


@njit(cache=True)
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
    """
    n = len(b)
    nf = len(f_anchor)
    g = p[P_G]
    gain_max = 0.0
    for q in range(len(excl_gain)):
        if abs(excl_gain[q]) > gain_max:
            gain_max = abs(excl_gain[q])
    h = np.zeros(NX)
    ph = np.zeros(NX)
    j = 0
    for i in range(n):
        bi = b[i]
        if m[M_STARTED] == 0.0:
            m[M_STARTED] = 1.0
            m[M_LAST_B] = bi
        dt = bi - m[M_LAST_B]
        if dt > 0.0:
            # without w nothing pins k: it walks as on the roughest ride
            rough = m[M_ROUGH] if p[P_USE_W] != 0.0 else 1.0
            _predict(x, cov, dt, p, not (bi - m[M_LAST_FRAME] <= p[P_COAST]), rough)
        m[M_LAST_B] = bi
        # -- channel noise from the parity residual (rigid-body motion does not show in it)
        r_i = residual[i]
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
        while j < nf and f_anchor[j] == i:
            z = f_speed[j]
            when = f_when[j]
            m[M_LAST_SEEN] = when
            m[M_STILL] = 1.0 if f_still[j] else 0.0
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
            if f_restart[j] or m[M_HAVE_V] == 0.0:
                _restart_speed(x, cov, z, rv)
                m[M_HAVE_V] = 1.0
                m[M_STREAK_T0] = math.nan
                m[M_LAST_FRAME] = when
                j += 1
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
            # odometer noise from the innovations within P_LEARN (vibration, coarse
            # quantisation): rejected ones too, or a gate set too tight would never widen;
            # a slide's frames soon pass P_LEARN and stay out
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
                            m[M_STREAK_T0] = math.nan
                            m[M_LAST_FRAME] = when
                        elif span >= 3.0 * p[P_RESET]:
                            # slipping for this long: take the odometer's speed, keep s
                            _restart_speed(x, cov, z, rv)
                            m[M_STREAK_T0] = math.nan
                            m[M_LAST_FRAME] = when
            j += 1
        coasting = not (bi - m[M_LAST_SEEN] <= p[P_COAST])
        if latched[i] > 0:
            # an exclusion by the residual or a stuck code: the channel's error grew until
            # now and its slow part went into s. Its size is the residual's slow mean over
            # the channel's parity weight; its share of u, that times the u weight
            leak = m[M_RESLOW] * excl_gain[latched[i] - 1]
            x[IS] -= leak
            cov[IS, IS] += leak * leak
        if r_i == r_i and dt > 0.0:
            m[M_RESLOW] += dt / p[P_RESLOW_TAU] * (r_i - m[M_RESLOW])
        # -- specific force along the track: u = a + s
        ui = u[i]
        have_u = ui == ui
        # the parity residual speaks of the channels in u and w only while all three are
        all3 = r_i == r_i and mask[i] == 7
        if have_u:
            noise2 = m[M_NOISE2] if m[M_NOISE2] > p[P_NOISE_FLOOR] else p[P_NOISE_FLOOR]
            r_u = noise2 * ru_of_mask[mask[i]]
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
            _update(x, cov, h, nu_u, r_u, ph)
            # w only while the channels agree: a drifting channel bends w as a curve would
            if p[P_USE_W] != 0.0 and not (all3 and abs(m[M_RESLOW]) > p[P_WRES_MAX]):
                _w_block(x, cov, m, p, h, ph, bi, w[i], noise2 * rw_of_mask[mask[i]])
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
        s_est = x[IS]
        c2 = g * g - s_est * s_est
        if c2 > 0.0 and cov[IS, IS] >= 0.0:
            c = math.sqrt(c2)
            grad = 1000.0 * s_est / c
            # a slow parity residual means one channel is off by residual / parity weight
            # and u by that times its u weight; which channel is not known yet, so the
            # largest share counts until the isolation settles it
            # (once it stands out of its own noise: 4 sigma of a moving mean of white noise)
            slow = abs(m[M_RESLOW]) if all3 else 0.0
            if dt > 0.0 and slow * slow <= 16.0 * m[M_NOISE2] * dt / (2.0 * p[P_RESLOW_TAU]):
                slow = 0.0
            slow *= gain_max
            pend = m[M_WPEND]
            var = cov[IS, IS] + slow * slow + p[P_BIAS] * p[P_BIAS] + pend * pend
            sigma = 1000.0 * g * g / (c2 * c) * math.sqrt(var)
        else:
            grad = math.nan
            sigma = math.nan
        out_sigma[i] = sigma
        out_grad[i] = grad if (have_u and sigma <= p[P_LIMIT]) else math.nan
        out_suspect[i] = m[M_SUSPECT] != 0.0
        out_coast[i] = coasting
        out_accel[i] = x[IA]
