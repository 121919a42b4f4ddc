"""Small dense products and the SPD inverse in plain loops.

numba's ``@`` and ``np.linalg`` call BLAS/LAPACK through SciPy, which the bench does not
depend on; for 8 x 8 matrices plain loops are as fast, and their order of operations is
fixed, so results do not depend on a library's blocking.
"""

from __future__ import annotations

import numpy as np

from bench.fusion.model._jit import jit


@jit
def mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a b."""
    n, m, p = a.shape[0], a.shape[1], b.shape[1]
    out = np.zeros((n, p))
    for i in range(n):
        for k in range(m):
            aik = a[i, k]
            if aik != 0.0:
                for j in range(p):
                    out[i, j] += aik * b[k, j]
    return out


@jit
def mv(a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """a x."""
    out = np.zeros(a.shape[0])
    for i in range(a.shape[0]):
        acc = 0.0
        for k in range(a.shape[1]):
            acc += a[i, k] * x[k]
        out[i] = acc
    return out


@jit
def sandwich(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """a p a^T, symmetrised (p symmetric)."""
    out = mm(mm(a, p), a.T.copy())
    sym: np.ndarray = 0.5 * (out + out.T)
    return sym


@jit
def spd_inverse(s: np.ndarray) -> np.ndarray:
    """S^-1 of a symmetric positive definite S, by its Cholesky factor L (S = L L^T)."""
    m = s.shape[0]
    low = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1):
            acc = s[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            if i == j:
                low[i, i] = np.sqrt(acc)
            else:
                low[i, j] = acc / low[j, j]
    inv_low = np.zeros((m, m))  # L^-1, lower triangular
    for i in range(m):
        inv_low[i, i] = 1.0 / low[i, i]
        for j in range(i):
            acc = 0.0
            for k in range(j, i):
                acc -= low[i, k] * inv_low[k, j]
            inv_low[i, j] = acc / low[i, i]
    return mm(inv_low.T.copy(), inv_low)
