"""The joint filter's compiled kernel: speed, acceleration and gradient from u and SPEED_REF.

One sequential loop over a batch of samples (and the SPEED_REF frames they apply), compiled
by numba. Batch (replay) and streaming (live) both call this very function, with the state
carried between calls in small float64 arrays, so the results are the same bits however a
stream is cut: a Kalman filter is a recursion, and a recursion run by one machine code in
one order does not depend on where the calls start and stop. No fastmath: IEEE semantics.

State x (see docs/ESTIMATOR.md):

====  ========================================================================
v     speed along the track, m/s, signed like SPEED_REF
a     acceleration dv/dt, m/s^2 (random walk in time)
s     g sin(alpha): gravity along the track, m/s^2 (random walk in distance)
k     ds/dx, the gradient's rate per metre (vertical curves; random walk in distance)
l     odometer latency beyond the clock alignment, s (constant unless enabled)
====  ========================================================================

Process over dt with d = |v| dt: v += a dt (+ white-jerk terms), s += k v dt; s and k
take process noise only per metre travelled, so a train at rest keeps its gradient.
Measurements: u = a + s at every sample (R from the channel noise and the subset's
(H^T H)^-1); odometer z = v - (delta + l) a at every applied SPEED_REF frame, gated by its
innovation (slip and slide); a = 0 and v = 0 at standstill (zero-velocity update).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

NX = 5
IV, IA, IS, IK, IL = 0, 1, 2, 3, 4

# -- misc state slots (float64 array ``m``) ------------------------------------------------
M_STARTED = 0  # 1 after the first sample
M_LAST_B = 1  # board time of the previous sample, s
M_NOISE2 = 2  # channel noise variance estimate, (m/s^2)^2
M_NOISE_N = 3  # residuals averaged so far (for the first-second mean)
M_LAST_FRAME = 4  # board time of the newest SPEED_REF frame, s (-inf: none yet)
M_STILL = 5  # the newest frame said standstill
M_SUSPECT = 6  # odometer suspect
M_STREAK_T0 = 7  # board time of the first rejected frame of the current streak (NaN: none)
M_STREAK_NU0 = 8  # its innovation
M_OK_SINCE = 9  # board time of the first accepted frame since the last rejection (NaN)
M_ZUPT_FROM = 10  # zero-velocity updates blocked before this board time
M_HAVE_V = 11  # the speed has been initialised from an odometer frame
M_RV = 12  # innovation-based odometer noise variance estimate
M_LAST_SEEN = 13  # board time of the newest frame measured (applied or rejected)
M_TREND = 14  # moving mean of the normalised odometer innovations (grade manoeuvres)
M_TREND_FROM = 15  # board time before which no new manoeuvre is declared
M_RESLOW = 16  # slow mean of the parity residual, m/s^2
M_QUANT = 17  # least non-zero step between odometer readings, m/s (inf: none yet)
M_LAST_Z = 18  # the previous reading, m/s
M_HAVE_Z = 19  # 1 once there is a previous reading
M_SIZE = 20

# -- parameters (float64 array ``p``) ------------------------------------------------------
P_QA = 0  # acceleration random walk, (m/s^2)^2/s
P_QS = 1  # gradient (s) random walk per metre, (m/s^2)^2/m
P_QK = 2  # grade-rate random walk per metre, ((m/s^2)/m)^2/m
P_QL = 3  # latency random walk, s^2/s
P_RV = 4  # least odometer noise variance (floor^2 + quantum^2/12), (m/s)^2
P_GATE = 5  # innovation gate, nu^2/S beyond this is rejected
P_RECOVER = 6  # s of accepted frames before "suspect" clears
P_RESET = 7  # s of rejected frames before the speed restarts at the odometer
P_SLIP = 8  # innovation slope (m/s^2) beyond which a rejected streak is slip/slide
P_COAST = 9  # s without SPEED_REF before "coasting"
P_RZ = 10  # zero-velocity update: acceleration variance, (m/s^2)^2
P_ZGATE = 11  # |u - s| beyond this (m/s^2) blocks the zero-velocity update
P_ZHOLD = 12  # s the zero-velocity update stays blocked after that
P_NOISE_FLOOR = 13  # channel noise variance floor, (m/s^2)^2
P_NOISE_TAU = 14  # s, time constant of the channel noise estimate
P_G = 15  # gravity, m/s^2
P_LIMIT = 16  # gradient withheld when its 1-sigma exceeds this, permil
P_S0 = 17  # initial 1-sigma of s, m/s^2
P_K0 = 18  # initial 1-sigma of k, (m/s^2)/m
P_A0 = 19  # initial 1-sigma of a, m/s^2
P_L0 = 20  # initial latency, s
P_LSIG = 21  # initial 1-sigma of the latency, s (0: not estimated)
P_RV_MAX = 22  # cap of the innovation-based odometer noise variance
P_RV_TAU = 23  # frames, time constant of that estimate
P_RV0 = 24  # odometer noise variance assumed at the start, (m/s)^2
P_RESLOW_TAU = 25  # s, time constant of the residual's slow mean
P_TREND_ALPHA = 26  # weight of a new frame in that moving mean
P_TREND_LIMIT = 27  # |moving mean| beyond this: the grade's rate has changed
P_KJUMP = 28  # 1-sigma added to k then, (m/s^2)/m
P_SJUMP = 29  # 1-sigma added to s then, m/s^2
P_UGATE = 30  # u innovation beyond this (nu^2/S): the acceleration stepped
P_QK_BLIND = 31  # k's random walk per metre while no odometer frame is accepted
P_LEARN = 32  # innovations (nu^2/S) up to this feed the odometer noise estimate
P_RES_LIMIT = 33  # residual limit, m/s^2 (clip of the residual's statistics)
P_LAT_ACC = 34  # m/s^2: the latency is estimated only while |a| exceeds this
P_SIZE = 35


def new_state(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, P, m) before the first sample."""
    x = np.zeros(NX)
    x[IL] = p[P_L0]
    cov = np.zeros((NX, NX))
    cov[IV, IV] = 100.0  # speed unknown until an odometer frame or a standstill says it
    cov[IA, IA] = p[P_A0] ** 2
    cov[IS, IS] = p[P_S0] ** 2
    cov[IK, IK] = p[P_K0] ** 2
    cov[IL, IL] = p[P_LSIG] ** 2
    m = np.zeros(M_SIZE)
    m[M_LAST_FRAME] = -math.inf
    m[M_LAST_SEEN] = -math.inf
    m[M_STREAK_T0] = math.nan
    m[M_OK_SINCE] = math.nan
    m[M_ZUPT_FROM] = -math.inf
    m[M_RV] = p[P_RV0]
    m[M_QUANT] = math.inf
    return x, cov, m


@njit(cache=True)
def _update(x, cov, h, nu, r, ph):  # type: ignore[no-untyped-def]
    """Scalar measurement update with row h (NX,), innovation nu and variance r (``ph``:
    scratch of NX). P -= K (P h)^T, then symmetrised. Returns the innovation variance."""
    for i in range(NX):
        acc = 0.0
        for j in range(NX):
            acc += cov[i, j] * h[j]
        ph[i] = acc
    s = r
    for i in range(NX):
        s += h[i] * ph[i]
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
def _innov_var(cov, h, r):  # type: ignore[no-untyped-def]
    s = r
    for i in range(NX):
        acc = 0.0
        for j in range(NX):
            acc += cov[i, j] * h[j]
        s += h[i] * acc
    return s


@njit(cache=True)
def _predict(x, cov, dt, p, blind):  # type: ignore[no-untyped-def]
    """x, P over dt seconds. EKF: s += k v dt is bilinear; F = I + dt (e_v e_a^T + k e_s e_v^T
    + v e_s e_k^T), applied to P's rows then columns in place (row s before row v, which
    it reads; likewise the columns). ``blind``: no odometer frame is being accepted, so
    the vertical-curve detector cannot see a curve start: k's process noise per metre is
    then the one that covers such jumps (P_QK_BLIND)."""
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
        qk = p[P_QK_BLIND] if blind else p[P_QK]
        cov[IS, IS] += qs * d + qk * d * d * d / 3.0
        cov[IS, IK] += qk * d * d / 2.0
        cov[IK, IS] += qk * d * d / 2.0
        cov[IK, IK] += qk * d
    if p[P_LSIG] > 0.0:
        cov[IL, IL] += p[P_QL] * dt


@njit(cache=True)
def _restart_speed(x, cov, z, r):  # type: ignore[no-untyped-def]
    """Speed from the odometer (z, variance r), uncorrelated with the rest."""
    x[IV] = z
    for i in range(NX):
        cov[IV, i] = 0.0
        cov[i, IV] = 0.0
    cov[IV, IV] = r


@njit(cache=True)
def run(  # type: ignore[no-untyped-def]
    x,
    cov,
    m,
    p,
    b,
    u,
    mask,
    residual,
    latched,
    ru_of_mask,
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

    b: board time (s) per sample; u: specific force along the track (NaN without two
    channels); mask: channel-mask code per sample; residual: parity residual (NaN without
    three channels); latched: channel (1..3) whose exclusion by the residual or as stuck
    starts at this sample, else 0; ru_of_mask: (H^T H)^-1 uu per mask code (inf below two
    channels); excl_gain: per channel, its u weight over its parity weight.
    Frames: anchor (sample index in this batch that first applies it, non-decreasing),
    board time it was measured, speed m/s, restart (after a long gap), standstill.
    """
    n = len(b)
    nf = len(f_anchor)
    g = p[P_G]
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
            _predict(x, cov, dt, p, not (bi - m[M_LAST_FRAME] <= p[P_COAST]))
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
            for q in range(NX):
                h[q] = 0.0
            h[IV] = 1.0
            h[IA] = -lag
            # the latency shows only in motion: near standstill the odometer's dead band
            # (it reads 0 until a whole quantum) would pass for latency
            moving = z != 0.0
            if p[P_LSIG] > 0.0 and moving and abs(x[IA]) > p[P_LAT_ACC]:
                h[IL] = -x[IA]
            nu = z - (x[IV] - lag * x[IA])
            s_nu = _innov_var(cov, h, rv)
            # a reading one quantum off is what a coarse odometer does, not a slip
            reach = math.sqrt(p[P_GATE] * s_nu) + quant
            accepted = abs(nu) <= reach
            if accepted:
                _update(x, cov, h, nu, rv, ph)
                m[M_LAST_FRAME] = when
                m[M_STREAK_T0] = math.nan
                if m[M_OK_SINCE] != m[M_OK_SINCE]:
                    m[M_OK_SINCE] = when
                if m[M_SUSPECT] != 0.0 and when - m[M_OK_SINCE] >= p[P_RECOVER]:
                    m[M_SUSPECT] = 0.0
                # a vertical curve starts or ends: k jumps, which its slow random walk cannot
                # follow; innovations of one sign in a row show it (as a manoeuvre does)
                tr = m[M_TREND] + p[P_TREND_ALPHA] * (nu / math.sqrt(s_nu) - m[M_TREND])
                m[M_TREND] = tr
                if abs(tr) > p[P_TREND_LIMIT] and when >= m[M_TREND_FROM]:
                    cov[IK, IK] += p[P_KJUMP] * p[P_KJUMP]
                    cov[IS, IS] += p[P_SJUMP] * p[P_SJUMP]
                    m[M_TREND] = 0.0
                    m[M_TREND_FROM] = when + 0.5
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
            _update(x, cov, h, nu_u, r_u, ph)
            # -- zero-velocity update at standstill (odometer at 0 for standstill_s)
            if m[M_STILL] != 0.0 and not coasting:
                if abs(ui - x[IS]) > p[P_ZGATE]:
                    m[M_ZUPT_FROM] = bi + p[P_ZHOLD]  # the accelerometers feel motion
                if bi >= m[M_ZUPT_FROM]:
                    for q in range(NX):
                        h[q] = 0.0
                    h[IA] = 1.0
                    _update(x, cov, h, -x[IA], p[P_RZ], ph)
                    for q in range(NX):
                        h[q] = 0.0
                    h[IV] = 1.0
                    _update(x, cov, h, -x[IV], p[P_RV], ph)
                    m[M_HAVE_V] = 1.0
        # -- output: gradient = 1000 tan(asin(s/g)) and its 1-sigma
        s_est = x[IS]
        c2 = g * g - s_est * s_est
        if c2 > 0.0 and cov[IS, IS] >= 0.0:
            c = math.sqrt(c2)
            grad = 1000.0 * s_est / c
            sigma = 1000.0 * g * g / (c2 * c) * math.sqrt(cov[IS, IS])
        else:
            grad = math.nan
            sigma = math.nan
        out_sigma[i] = sigma
        out_grad[i] = grad if (have_u and sigma <= p[P_LIMIT]) else math.nan
        out_suspect[i] = m[M_SUSPECT] != 0.0
        out_coast[i] = coasting
        out_accel[i] = x[IA]
