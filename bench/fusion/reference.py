"""The device's reference method: per-pair gradients, two-out-of-three vote, fixed weights.

Pure numpy over (N, 3) arrays, float64 throughout, no I/O. The live path calls the same
function on each small batch of samples as it arrives, so live and replay results are the
same float64 values (element-wise ufuncs on contiguous arrays do not depend on length).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PAIRS = ((0, 1), (1, 2), (0, 2))
"""Slope values s1 = g12, s2 = g23, s3 = g13, as channel index pairs."""
VOTES = ((0, 1), (1, 2), (0, 2))
"""Votes v1 (s1, s2), v2 (s2, s3), v3 (s1, s3), as slope index pairs."""
MEMBERSHIP = np.array([[1, 0, 1], [1, 1, 0], [0, 1, 1]], dtype=np.int64)
"""MEMBERSHIP[k, v] = 1 when slope value k takes part in vote v."""


@dataclass(frozen=True, slots=True)
class ReferenceResult:
    slopes: np.ndarray  # (N, 3) g12, g23, g13 per mille; NaN where a channel is missing
    votes: np.ndarray  # (N, 3) bool v1, v2, v3
    weights: np.ndarray  # (N, 3) w12, w23, w13
    gradient: np.ndarray  # (N,) per mille; NaN where invalid
    valid: np.ndarray  # (N,) bool: at least one vote passed


def pair_gradients(acc: np.ndarray, angles_rad: np.ndarray, g: float) -> np.ndarray:
    """(N, 3) accelerations (NaN = unusable) -> (N, 3) slope values in per mille.

    cos(alpha_ij) = (a_i cos(theta_j) - a_j cos(theta_i)) / (g sin(theta_i - theta_j)),
    clamped to [-1, 1]; gradient = 1000 tan(alpha_ij), never negative.
    """
    acc = np.ascontiguousarray(acc, dtype=np.float64)
    th = np.asarray(angles_rad, dtype=np.float64)
    cos_th = np.cos(th)
    out = np.empty((acc.shape[0], 3), dtype=np.float64)
    for k, (i, j) in enumerate(PAIRS):
        denom = g * np.sin(th[i] - th[j])
        cos_alpha = (acc[:, i] * cos_th[j] - acc[:, j] * cos_th[i]) / denom
        np.clip(cos_alpha, -1.0, 1.0, out=cos_alpha)
        out[:, k] = 1000.0 * np.tan(np.arccos(cos_alpha))
    return out


def vote(slopes: np.ndarray, tolerance_permil: float) -> np.ndarray:
    """(N, 3) bool votes; a vote involving an uncomputable (NaN) slope value fails."""
    votes = np.empty(slopes.shape, dtype=bool)
    for v, (p, q) in enumerate(VOTES):
        votes[:, v] = np.abs(slopes[:, p] - slopes[:, q]) <= tolerance_permil
    return votes


def weights(votes: np.ndarray) -> np.ndarray:
    """Table 1: a slope value's weight = votes it passes in / (2 * passed votes); 0 when none."""
    passed = votes.astype(np.int64)
    takes_part = passed @ MEMBERSHIP.T  # (N, 3): passed votes each slope value is in
    total = passed.sum(axis=1, keepdims=True)
    w = np.zeros(votes.shape, dtype=np.float64)
    np.divide(takes_part, 2 * total, out=w, where=total > 0)
    return w


def fuse(
    acc: np.ndarray, angles_rad: np.ndarray, g: float, tolerance_permil: float
) -> ReferenceResult:
    """The whole reference method over a batch of samples."""
    slopes = pair_gradients(acc, angles_rad, g)
    votes = vote(slopes, tolerance_permil)
    w = weights(votes)
    valid = votes.any(axis=1)
    terms = np.where(w > 0, w * np.nan_to_num(slopes), 0.0)
    gradient = terms[:, 0] + terms[:, 1] + terms[:, 2]
    gradient[~valid] = np.nan
    return ReferenceResult(slopes, votes, w, gradient, valid)
