"""The joint filter's w measurement: the normal specific force, in block means.

On a vertical curve the car is pressed onto (or lifted off) its bogies by v^2/R, which
tells the grade's rate k long before the odometer can. A rough ride's bounce is taken out
of the block innovations by an adaptive notch, and a two-stage curve detector finds the
curves the vibration hides (docs/ESTIMATOR.md, measurement 3). Compiled by numba; called
from :func:`bench.fusion.joint_kernel.run`.
"""

from __future__ import annotations

import math

from numba import njit

from bench.fusion.joint_layout import (
    IB,
    IK,
    IS,
    IV,
    IZ,
    IZC,
    M_HALF_T0,
    M_JUMP_DK,
    M_NOTCH_IN,
    M_NOTCH_OUT,
    M_NOTCH_POW,
    M_NOTCH_TH,
    M_NOTCH_X1,
    M_NOTCH_X2,
    M_REWIND_AT,
    M_REWIND_DK,
    M_REWIND_FROM,
    M_REWIND_T,
    M_ROUGH,
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
    M_ZCLONE_T,
    M_ZVAR,
    NX,
    P_G,
    P_KMAX,
    P_NOTCH_MU,
    P_NOTCH_RHO,
    P_REWIND,
    P_WBLOCK,
    P_WCORR,
    P_WDET_MIN,
    P_WDET_SIGMA,
    P_WDET_TAU,
    P_WDET_VAR_TAU,
    P_WGATE,
    P_WROUGH,
    P_WVAR_TAU,
    P_ZMIS,
    P_ZTAU,
)
from bench.fusion.joint_updates import _innov_var, _update

W_SIGMA_S_MAX = 0.02  # m/s^2: w is used once s is known this well (2 permil)
NOTCH_LEAK = 0.005  # share of the power the notch removes that the z model leaves in R
HALF_WAY = 0.6  # share of the way to firing beyond which a pending curve widens the sigma
REWIND_EARLY_S = 0.05  # a rewind starts this much before the start the detector infers
AGE_REL = 0.3  # relative 1-sigma of the step age the curve detector infers


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
def _restart_detector(m):  # type: ignore[no-untyped-def]
    """The detector after it fired: its means from zero, nothing pending."""
    m[M_WE] = 0.0
    m[M_WE1] = 0.0
    m[M_WPEND] = 0.0
    m[M_HALF_T0] = math.nan


@njit(cache=True)
def _curve_detector(x, cov, m, p, nu, hk, bi, span, fresh):  # type: ignore[no-untyped-def]
    """A vertical curve's start or end under vibration: two cascaded moving means of the
    block innovations depart from zero by more than their learnt spread. Their ratio tells
    how long ago the step began and so its whole size. On a rough ride the kernel then
    rewinds to just before that start (M_REWIND_T; bench.fusion.joint_rewind) unless
    ``fresh`` (the block gate takes this step itself) or the start is out of reach;
    otherwise k's variance is raised here by that step's k, and s's by what that k has
    done since it began (correlated), so the next updates put both right. Past HALF_WAY
    to firing, that s error widens the output's sigma."""
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
    # past HALF_WAY to firing: a curve may have started, and s has been moving by its k since;
    # the output's sigma says so until the detector decides (the state is not touched)
    half = e * e > (HALF_WAY * p[P_WDET_SIGMA]) ** 2 * var and abs(e) > HALF_WAY * p[P_WDET_MIN]
    # the step the two means imply, and when it began (only past HALF_WAY: firing needs it too)
    age, step = 0.0, e1
    if half:
        age = _step_age(e1, e)
        # the step began before HALF_WAY was passed, by the age the means gave then; later
        # it cannot be older than that (a mean falling back, as the updates take the step
        # in, would read as a step from long ago)
        if m[M_HALF_T0] != m[M_HALF_T0]:
            m[M_HALF_T0] = bi - age * tau
        since = (bi - m[M_HALF_T0]) / tau
        age = since if age > since else age
        if age > 0.0:
            step = e1 / (1.0 - math.exp(-age))
    m[M_WPEND] = abs(step / hk) * abs(x[IV]) * age * tau if (half and hk != 0.0) else 0.0
    if big and bi >= m[M_WHOLD] and hk * p[P_KMAX] > abs(e):
        dk = step / hk
        kmax = p[P_KMAX]
        dk = kmax if dk > kmax else (-kmax if dk < -kmax else dk)
        t_on = bi - age * tau - REWIND_EARLY_S
        # only on a rough ride: on a smooth one the block gate takes a step at once (its
        # carry handles a block that straddles it), and w is precise enough for a replay
        # from a block's start to misread such a block as the whole step
        if (
            p[P_REWIND] > 0.0
            and m[M_ROUGH] >= 1.0
            and not fresh
            and age * tau <= p[P_REWIND]
            and (t_on > m[M_REWIND_FROM])
        ):
            # the kernel goes back to just before the curve began and replays since
            # (bench.fusion.joint_rewind): k's variance is raised there, not here
            m[M_REWIND_T] = t_on
            m[M_REWIND_DK] = dk
            m[M_REWIND_AT] = bi
        else:
            ds = dk * x[IV] * age * tau
            for i in range(NX):
                di = dk if i == IK else (ds if i == IS else 0.0)
                if di == 0.0:
                    continue
                for j in range(NX):
                    dj = dk if j == IK else (ds if j == IS else 0.0)
                    cov[i, j] += di * dj
            # the age itself is uncertain: what s did meanwhile is not all carried by k
            cov[IS, IS] += (AGE_REL * ds) * (AGE_REL * ds)
        _restart_detector(m)
        m[M_WHOLD] = bi + 2.0 * tau
    elif bi == m[M_REWIND_AT]:
        # the replay after a rewind reaches the sample that fired: the detector starts
        # afresh from here, as it did then
        _restart_detector(m)
        m[M_REWIND_AT] = math.nan
    elif not big:
        if not half:
            m[M_HALF_T0] = math.nan
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
    th = m[M_NOTCH_TH]  # starts at 0: a quarter of the block rate, until it learns the tone
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
def _clone_z(x, cov, m, bi):  # type: ignore[no-untyped-def]
    """zc = z, with z's covariance: the next block's vibration is (z - zc) / T."""
    x[IZC] = x[IZ]
    for j in range(NX):
        cov[IZC, j] = cov[IZ, j]
    for i in range(NX):
        cov[i, IZC] = cov[i, IZ]
    cov[IZC, IZC] = cov[IZ, IZ]
    m[M_ZCLONE_T] = bi


@njit(cache=True)
def _w_block(x, cov, m, p, h, ph, bi, wi, r_white):  # type: ignore[no-untyped-def]
    """Add sample w to the current block; at the block's end apply its mean.

    h(x) = c + v^2 k / c + b + (z - zc) / T with c = sqrt(g^2 - s^2): the normal specific
    force on a vertical curve (1/R = d alpha/dx, k = ds/dx = c / R) plus the car body's
    vertical vibration over the block, the change of its vertical velocity z. A suspension
    keeps z bounded, so the vibration's mean over a second is far smaller than a second of
    independent block errors would be, while a curve's v^2/R lasts: that is what lets w
    pin k on a rough ride. z's stationary variance comes from the blocks' learnt variance
    (vibration, floored at the sensors' white noise). Without z states (P_ZTAU = 0) the
    vibration is block noise, correlated over P_WCORR."""
    ztau = p[P_ZTAU]
    if m[M_WT0] != m[M_WT0]:
        m[M_WT0] = bi
        m[M_WSUM] = 0.0
        m[M_WCOUNT] = 0.0
        m[M_WFLOOR] = 0.0
        if ztau > 0.0 and m[M_ZCLONE_T] != m[M_ZCLONE_T]:
            _clone_z(x, cov, m, bi)
    m[M_WSUM] += wi
    m[M_WCOUNT] += 1.0
    m[M_WFLOOR] += r_white
    if bi - m[M_WT0] < p[P_WBLOCK]:
        return
    cnt = m[M_WCOUNT]
    mean = m[M_WSUM] / cnt
    floor = m[M_WFLOOR] / (cnt * cnt)
    # the block's length as its samples cover it, and the time since z was cloned: equal
    # when the clone was taken at the previous block's end
    step_b = (bi - m[M_WT0]) / (cnt - 1.0) if cnt > 1.0 else p[P_WBLOCK]
    t_z = bi - m[M_ZCLONE_T]
    use_z = ztau > 0.0 and abs(t_z - cnt * step_b) <= 0.5 * step_b
    m[M_WT0] = math.nan
    if cov[IS, IS] > W_SIGMA_S_MAX * W_SIGMA_S_MAX:
        # s not known yet (a start in motion): c = sqrt(g^2 - s^2) at a guessed s would put
        # the guess's cos error into b for good; w waits until u and the odometer tell s
        if ztau > 0.0:
            _clone_z(x, cov, m, bi)
        return
    g = p[P_G]
    v, s, k = x[IV], x[IS], x[IK]
    c2 = g * g - s * s
    if c2 <= 0.0:
        if ztau > 0.0:
            _clone_z(x, cov, m, bi)
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
    # a vertical curve starts or ends: k jumps, which its random walk per metre cannot
    # follow; the block tells by how much, when the train is fast enough for it to show
    gate = nu * nu > p[P_WGATE] * s_nu and h[IK] * p[P_KMAX] > math.sqrt(p[P_WGATE] * s_nu)
    _curve_detector(x, cov, m, p, nu, h[IK], bi, span, gate)
    carry = m[M_JUMP_DK]
    m[M_JUMP_DK] = 0.0
    if carry != 0.0:
        # the last block straddled a curve's start: its mean showed only part of the step,
        # and this block, wholly past it, may show the rest (as much again, at most)
        ds = carry * x[IV] * span
        cov[IK, IK] += carry * carry
        cov[IK, IS] += carry * ds
        cov[IS, IK] += carry * ds
        cov[IS, IS] += ds * ds
    if gate:
        # the step's size (at most the sharpest curve a line has)
        dk = nu / h[IK]
        dk = p[P_KMAX] if dk > p[P_KMAX] else (-p[P_KMAX] if dk < -p[P_KMAX] else dk)
        # and s has moved by the old k for the part of the block after the jump: both get
        # the matching (correlated) variance, so this block's update puts both right
        ds = dk * x[IV] * span
        cov[IK, IK] += dk * dk
        cov[IK, IS] += dk * ds
        cov[IS, IK] += dk * ds
        cov[IS, IS] += ds * ds
        m[M_JUMP_DK] = dk
    if use_z:
        # the vibration is z's change over the block; what the Gauss-Markov model misses of
        # it stays in R
        h[IZ] = 1.0 / t_z
        h[IZC] = -1.0 / t_z
        wv = m[M_WVAR] - floor if m[M_WVAR] > floor else 0.0
        # and what the notch took out of the bounce is not known to the last per cent: a
        # share of the power it removed stays in R (else k follows the notch's leftovers)
        gone = m[M_NOTCH_IN] - m[M_NOTCH_OUT] if m[M_NOTCH_IN] > m[M_NOTCH_OUT] else 0.0
        r_z = floor + p[P_ZMIS] * wv + NOTCH_LEAK * gone
        _update(x, cov, h, nu - (x[IZ] - x[IZC]) / t_z, r_z, ph)
    else:
        _update(x, cov, h, nu, r, ph)
    lim = p[P_WGATE] * s_nu
    e2 = lim if e2 > lim else (0.0 if e2 < 0.0 else e2)
    m[M_WVAR] += (e2 - m[M_WVAR]) / p[P_WVAR_TAU]
    # rough: the blocks' learnt spread on an absolute scale (a quiet w, however low its
    # noise, is smooth; a few hundredths of m/s^2 hide the start of a curve)
    rough = math.sqrt(m[M_WVAR]) / p[P_WROUGH] if m[M_WVAR] > 0.0 else 0.0
    m[M_ROUGH] = 1.0 if rough > 1.0 else rough
    if ztau > 0.0:
        # z's stationary variance from the block variance it explains: a block mean of
        # Gauss-Markov vibration has variance 2 zvar (1 - exp(-T / tau)) / T^2
        wv = m[M_WVAR] - floor if m[M_WVAR] > floor else 0.0
        tb = cnt * step_b
        m[M_ZVAR] = wv * tb * tb / (2.0 * (1.0 - math.exp(-tb / ztau)))
        _clone_z(x, cov, m, bi)
