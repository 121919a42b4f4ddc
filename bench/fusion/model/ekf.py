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
    return x_new, p, nis
