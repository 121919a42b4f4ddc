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
    """a p a^T for a symmetric p, as a (a p)^T, symmetrised: a is on the left of both
    products, so a sparse a (a transition matrix F) skips its zeros in both."""
    out = mm(a, mm(a, p).T.copy())
    n = out.shape[0]
    for i in range(n):
        for j in range(i):
            mean = 0.5 * (out[i, j] + out[j, i])
            out[i, j] = mean
            out[j, i] = mean
    return out


@jit
def sandwich_dense(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """a p a^T for a symmetric p and a dense a (a smoother gain): X = a p, then only the
    lower triangle of X a^T, mirrored (exactly symmetric, half the second product)."""
    xm = mm(a, p)
    n, m = a.shape[0], a.shape[1]
    out = np.empty((n, n))
    for i in range(n):
        for j in range(i + 1):
            acc = 0.0
            for k in range(m):
                acc += xm[i, k] * a[j, k]
            out[i, j] = acc
            out[j, i] = acc
    return out


@jit
def cholesky(s: np.ndarray) -> np.ndarray:
    """The lower-triangular L with L L^T = s (s symmetric positive semi-definite: a state
    known exactly, as a constant given a zero prior sigma is, has a zero pivot, and its
    row and column of L stay zero)."""
    m = s.shape[0]
    low = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1):
            acc = s[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            if i == j:
                low[i, i] = np.sqrt(acc) if acc > 0.0 else 0.0
            elif low[j, j] > 0.0:
                low[i, j] = acc / low[j, j]
    return low


@jit
def spd_solve(s: np.ndarray, b: np.ndarray) -> np.ndarray:
    """s^-1 b for a symmetric positive definite s: L y = b, then L^T x = y (cheaper than
    the inverse and a product when b has as many columns as s). A zero pivot (a state known
    exactly) gives 0 in its row: the smoother's gain does not move a known state."""
    low = cholesky(s)
    m, p = b.shape[0], b.shape[1]
    y = np.empty((m, p))
    for c in range(p):
        for i in range(m):
            acc = b[i, c]
            for k in range(i):
                acc -= low[i, k] * y[k, c]
            y[i, c] = acc / low[i, i] if low[i, i] > 0.0 else 0.0
        for i in range(m - 1, -1, -1):
            acc = y[i, c]
            for k in range(i + 1, m):
                acc -= low[k, i] * y[k, c]
            y[i, c] = acc / low[i, i] if low[i, i] > 0.0 else 0.0
    return y


@jit
def spd_inverse(s: np.ndarray) -> np.ndarray:
    """S^-1 of a symmetric positive definite S, by its Cholesky factor L (S = L L^T)."""
    m = s.shape[0]
    low = cholesky(s)
    inv_low = np.zeros((m, m))  # L^-1, lower triangular
    for i in range(m):
        inv_low[i, i] = 1.0 / low[i, i]
        for j in range(i):
            acc = 0.0
            for k in range(j, i):
                acc -= low[i, k] * inv_low[k, j]
            inv_low[i, j] = acc / low[i, i]
    return mm(inv_low.T.copy(), inv_low)
