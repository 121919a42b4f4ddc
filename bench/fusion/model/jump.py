"""Vertical-curve onsets as jumps of K: a generalised likelihood-ratio test over the last
blocks (Willsky and Jones 1976) with the state corrected at the onset found.

A vertical curve's start or end is a step nu of K (= dS/dx = g / R on a curve of radius R)
at some block theta, which K's random walk follows only slowly. Each hypothesis "K stepped
by nu just before block theta" is followed from theta on, for every block of the last
``curve_window_s``, by two state-space vectors, both linear in nu (per unit nu):

    M  the true state's deviation caused by the step: M_theta = e_K, M <- Phi M over each step
    F  the filter's estimate's response to it:        F_theta = 0,   F <- Phi F over each step,
       and at each update applied (gain G, rows H)     F <- F + G H (M - F)

so each innovation nu_j = (H (M - F)) nu + white, and over the hypothesis's updates

    d = sum (H (M - F))^T S^-1 nu_j,   c = sum (H (M - F))^T S^-1 H (M - F).

With a prior nu ~ N(0, s^2) (``curve_rate_step_per_m``) the step's marginal likelihood ratio
against no step is exp(d^2 / (2 (c + 1/s^2))) / sqrt(1 + s^2 c) (Gustafsson's marginalised
GLR), and the prior odds of a step in the block are its distance travelled over the mean
distance between steps (``curve_spacing_m``): the test is posterior odds > 1. The step found
(the hypothesis of the largest odds) is nu = d / (c + 1/s^2) with variance 1 / (c + 1/s^2),
and the filter that had known the step at theta would be at

    x + (M - F) nu,   P + (M - F) (M - F)^T / (c + 1/s^2)

(exactly, for a linear model): that is the correction. Then every hypothesis starts again.
The smoother sees the correction as process noise into the block it was found in (its
covariance added to that block's predicted P), so it does not carry the step back before
it was found. All of it depends on the blocks only (never on a batch cut): the hypotheses
are carried between calls in one array, like x and P.

Each hypothesis is one row of that array: M, F, d, c, its age in blocks (-1: empty) and
the log of its prior odds against.
"""

from __future__ import annotations

import math

import numpy as np

from bench.fusion.model._jit import jit
from bench.fusion.model.state import NX, P_KJ, P_KMIN, P_KSP, K, ModelParams, V

M0, F0 = 0, NX
D, CI, AGE, LOGPRIOR, T0 = 2 * NX, 2 * NX + 1, 2 * NX + 2, 2 * NX + 3, 2 * NX + 4
WIDTH = 2 * NX + 5


def hypotheses(prm: ModelParams, block_s: float) -> np.ndarray:
    """An empty window of onset hypotheses: one row per block of ``curve_window_s``."""
    n = max(1, round(prm.curve_window_s / block_s))
    out = np.zeros((n, WIDTH))
    out[:, AGE] = -1.0
    return out


@jit
def propagate(glr: np.ndarray, phi: np.ndarray, dist: float, t: float, prm: np.ndarray) -> None:
    """Over one step (transition phi, |v| dt = dist metres travelled, t the block's
    mid-time s): every hypothesis's M and F by phi, one block older; the oldest (or an empty
    row) becomes the hypothesis of a step in this step, if the train moved (no curve starts
    at a standstill)."""
    if prm[P_KJ] <= 0.0:
        return
    # phi is the identity but for a few entries: vec + (phi - I) vec over those alone
    rows, cols, vals = np.empty(NX * NX, np.int64), np.empty(NX * NX, np.int64), np.empty(NX * NX)
    nnz = 0
    for i in range(NX):
        for j in range(NX):
            d = phi[i, j] - (1.0 if i == j else 0.0)
            if d != 0.0:
                rows[nnz], cols[nnz], vals[nnz] = i, j, d
                nnz += 1
    tmp = np.empty(2 * NX)
    empty, oldest, age_max = -1, -1, -1.0
    for h in range(glr.shape[0]):
        if glr[h, AGE] < 0.0:
            if empty < 0:
                empty = h
            continue
        for base in (M0, F0):
            for i in range(NX):
                tmp[i] = glr[h, base + i]
            for e in range(nnz):
                glr[h, base + rows[e]] += vals[e] * tmp[cols[e]]
        glr[h, AGE] += 1.0
        if glr[h, AGE] > age_max:
            oldest, age_max = h, glr[h, AGE]
    if dist <= 0.0:
        return
    row = glr[empty if empty >= 0 else oldest]
    row[:] = 0.0
    row[M0 + K] = 1.0
    row[LOGPRIOR] = math.log(max(prm[P_KSP] / dist, 1.0))
    row[T0] = t


@jit
def follow(
    glr: np.ndarray, jac: np.ndarray, gain: np.ndarray, s_inv: np.ndarray, nu: np.ndarray
) -> None:
    """One update applied (rows jac, gain, S^-1, innovation nu): each hypothesis's
    signature H (M - F) accumulated into d and c, and the filter's response F moved."""
    m = len(nu)
    cols = np.empty(NX, np.int64)  # the states the rows read (a few)
    nc = 0
    for j in range(NX):
        for a in range(m):
            if jac[a, j] != 0.0:
                cols[nc] = j
                nc += 1
                break
    sig = np.empty(m)
    w = np.empty(m)
    for h in range(glr.shape[0]):
        if glr[h, AGE] < 0.0:
            continue
        for a in range(m):
            acc = 0.0
            for e in range(nc):
                j = cols[e]
                acc += jac[a, j] * (glr[h, M0 + j] - glr[h, F0 + j])
            sig[a] = acc
        for a in range(m):
            acc = 0.0
            for b in range(m):
                acc += s_inv[a, b] * sig[b]
            w[a] = acc
        for a in range(m):
            glr[h, D] += w[a] * nu[a]
            glr[h, CI] += w[a] * sig[a]
        for i in range(NX):
            acc = 0.0
            for a in range(m):
                acc += gain[i, a] * sig[a]
            glr[h, F0 + i] += acc


@jit
def restart_speed(glr: np.ndarray) -> None:
    """V taken from a SPEED_REF frame (a restart): its estimate no longer responds to a step."""
    for h in range(glr.shape[0]):
        glr[h, F0 + V] = glr[h, M0 + V]


@jit
def test(
    glr: np.ndarray, x: np.ndarray, cov: np.ndarray, t: float, prm: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """After a block's updates: the hypothesis of the largest posterior odds, if above 1,
    corrected for. Returns (x, P, the covariance added, the step nu found (0: none), its
    age in blocks: the onset was that many blocks ago (-1: none))."""
    added = np.zeros((NX, NX))
    s2 = prm[P_KJ] * prm[P_KJ]
    if s2 <= 0.0:
        return x, cov, added, 0.0, -1.0
    best, best_score = -1, 0.0
    for h in range(glr.shape[0]):
        if glr[h, AGE] < 0.0 or glr[h, CI] <= 0.0 or t - glr[h, T0] < prm[P_KMIN]:
            continue
        info = glr[h, CI] + 1.0 / s2
        score = 0.5 * (glr[h, D] * glr[h, D] / info - math.log(1.0 + s2 * glr[h, CI]))
        score -= glr[h, LOGPRIOR]
        if score > best_score:
            best, best_score = h, score
    if best < 0:
        return x, cov, added, 0.0, -1.0
    info = glr[best, CI] + 1.0 / s2
    step = glr[best, D] / info
    age = glr[best, AGE]
    dm = glr[best, M0 : M0 + NX] - glr[best, F0 : F0 + NX]
    for i in range(NX):
        for j in range(NX):
            added[i, j] = dm[i] * dm[j] / info
    x_new = x + dm * step
    cov_new = cov + added
    glr[:, :] = 0.0
    glr[:, AGE] = -1.0
    return x_new, cov_new, added, step, age
