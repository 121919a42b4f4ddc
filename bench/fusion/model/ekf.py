"""One generic extended-Kalman predict and one generic update in Joseph form.

The Joseph form P = (I - K H) P (I - K H)^T + K R K^T keeps P symmetric positive
semi-definite for any gain, so a gated or clamped update cannot break the covariance the
sigmas come from. The innovation covariance is inverted by Cholesky (it is SPD).
"""

from __future__ import annotations

import numpy as np

from bench.fusion.model._jit import jit
from bench.fusion.model.linalg import mm, mv, sandwich, spd_inverse


@jit
def predict(
    x_next: np.ndarray, jac: np.ndarray, cov: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(x, F P F^T + Q) with x = f(x) computed by the caller and F its Jacobian."""
    return x_next, sandwich(jac, cov) + q


@jit
def _times(m: np.ndarray, h: np.ndarray) -> np.ndarray:
    """m h for a row h of mostly zeros (an odometer row touches four states)."""
    out = np.zeros(m.shape[0])
    for i in range(m.shape[0]):
        acc = 0.0
        for j in range(len(h)):
            if h[j] != 0.0:
                acc += m[i, j] * h[j]
        out[i] = acc
    return out


@jit
def _update_scalar(
    x: np.ndarray, cov: np.ndarray, nu: float, h: np.ndarray, r: float
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, float]:
    """:func:`update` for one measurement (the odometer's), in loops without temporaries:
    the same Joseph form X = P - k (P h)^T, X - (X h) k^T + r k k^T; also the gain k and
    the innovation variance s."""
    n = len(x)
    ph = _times(cov, h)
    s = r
    for j in range(n):
        s += h[j] * ph[j]
    gain = ph / s
    x_new = x + gain * nu
    xm = np.empty((n, n))
    for i in range(n):
        for j in range(n):
            xm[i, j] = cov[i, j] - gain[i] * ph[j]
    xh = _times(xm, h)
    p = np.empty((n, n))
    for i in range(n):
        for j in range(i + 1):
            a = xm[i, j] - xh[i] * gain[j] + r * gain[i] * gain[j]
            b = xm[j, i] - xh[j] * gain[i] + r * gain[j] * gain[i]
            p[i, j] = p[j, i] = 0.5 * (a + b)
    return x_new, p, nu * nu / s, gain, s


@jit
def update_full(
    x: np.ndarray,
    cov: np.ndarray,
    z: np.ndarray,
    hx: np.ndarray,
    jac: np.ndarray,
    r: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`update` and what it applied: (x, P, NIS, gain K (n, m), S^-1 (m, m), the
    innovation nu (m,)), which the jump test (bench.fusion.model.jump) follows."""
    if len(z) == 1:
        nu1 = z[0] - hx[0]
        x1, p1, nis1, g1, s1 = _update_scalar(x, cov, nu1, jac[0], r[0, 0])
        gain1 = np.empty((len(x), 1))
        gain1[:, 0] = g1
        s_inv1 = np.empty((1, 1))
        s_inv1[0, 0] = 1.0 / s1
        nuv = np.empty(1)
        nuv[0] = nu1
        return x1, p1, nis1, gain1, s_inv1, nuv
    nu = z - hx
    ph = mm(cov, jac.T.copy())
    s_inv = spd_inverse(mm(jac, ph) + r)
    gain = mm(ph, s_inv)
    x_new = x + mv(gain, nu)
    # (I - K H) P (I - K H)^T without forming I - K H: X = P - K (H P), X - (X H^T) K^T,
    # each product n x n x m (m the rows measured), not n^3
    gt = gain.T.copy()
    xm = cov - mm(gain, ph.T.copy())
    joseph = xm - mm(mm(xm, jac.T.copy()), gt)
    p = joseph + mm(gain, mm(r, gt))
    p = 0.5 * (p + p.T)
    nis = 0.0
    s_nu = mv(s_inv, nu)
    for i in range(len(nu)):
        nis += nu[i] * s_nu[i]
    return x_new, p, nis, gain, s_inv, nu


@jit
def update(
    x: np.ndarray,
    cov: np.ndarray,
    z: np.ndarray,
    hx: np.ndarray,
    jac: np.ndarray,
    r: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float]:
    """The update by measurement z (expected hx, H = jac, noise R): (x, P, NIS), NIS the
    normalised innovation squared nu^T S^-1 nu (chi-square with len(z) degrees of freedom
    when the model is right: the same number gates and isolates)."""
    if len(z) == 1:
        x1, p1, nis1, _, _ = _update_scalar(x, cov, z[0] - hx[0], jac[0], r[0, 0])
        return x1, p1, nis1
    xn, pn, nis, _, _, _ = update_full(x, cov, z, hx, jac, r)
    return xn, pn, nis
