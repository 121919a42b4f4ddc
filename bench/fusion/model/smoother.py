"""Rauch-Tung-Striebel fixed-interval smoother on the filter's own model, for logs.

The forward pass stores, per step k, the predicted (x_k|k-1, P_k|k-1), the filtered
(x_k|k, P_k|k) and the Jacobian F_k that took step k-1 to k. The backward pass is

    C_k = P_k|k F_k+1^T P_k+1|k^-1   (C_k^T solved from P_k+1|k C_k^T = F_k+1 P_k|k)
    x_k|N = x_k|k + C_k (x_k+1|N - x_k+1|k)
    P_k|N = P_k|k + C_k (P_k+1|N - P_k+1|k) C_k^T

which for a linear Gaussian model is the exact posterior given every measurement, and for
the EKF the usual linearisation about the filtered track.
"""

from __future__ import annotations

import numpy as np

from bench.fusion.model._jit import jit
from bench.fusion.model.linalg import mm, mv, sandwich_dense, spd_solve


@jit
def rts(
    x_pred: np.ndarray,
    p_pred: np.ndarray,
    x_filt: np.ndarray,
    p_filt: np.ndarray,
    jac: np.ndarray,
    covariance: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed (N, n) states and (N, n, n) covariances from the forward pass's arrays
    (jac[k] takes step k-1 to k; jac[0] is unused). Without ``covariance`` the states alone
    (they do not depend on it) and the filtered covariances returned as they are."""
    n = x_filt.shape[0]
    xs = x_filt.copy()
    ps = p_filt.copy()
    for k in range(n - 2, -1, -1):
        # F P is P F^T transposed (P symmetric), and F on the left skips its zeros
        gain = spd_solve(p_pred[k + 1], mm(jac[k + 1], p_filt[k])).T.copy()
        xs[k] = x_filt[k] + mv(gain, xs[k + 1] - x_pred[k + 1])
        if covariance:
            ps[k] = p_filt[k] + sandwich_dense(gain, ps[k + 1] - p_pred[k + 1])
    return xs, ps
