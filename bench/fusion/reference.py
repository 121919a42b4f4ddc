"""The device's reference method: per-pair gradients, two-out-of-three vote, fixed weights.

Pure numpy over (N, 3) arrays, float64 throughout, no I/O. The live path calls the same
function on each small batch of samples as it arrives, so live and replay results are the
same float64 values (element-wise ufuncs on contiguous arrays do not depend on length).

Internally the three pairs (and votes) are the rows of channel-major (3, N) arrays: one
ufunc call then covers all three, along contiguous memory, which is what a replay batch
wants (long rows) and what a live push of a sample or two wants (few calls). The results
are (N, 3) views of those arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

PAIRS = ((0, 1), (1, 2), (0, 2))
"""Slope values s1 = g12, s2 = g23, s3 = g13, as channel index pairs."""
VOTES = ((0, 1), (1, 2), (0, 2))
"""Votes v1 (s1, s2), v2 (s2, s3), v3 (s1, s3), as slope index pairs."""
MEMBERSHIP = np.array([[1, 0, 1], [1, 1, 0], [0, 1, 1]], dtype=np.int64)
"""MEMBERSHIP[k, v] = 1 when slope value k takes part in vote v."""

_PAIR_I, _PAIR_J, _VOTE_P, _VOTE_Q = (
    np.array([pair[k] for pair in pairs], dtype=np.intp) for pairs in (PAIRS, VOTES) for k in (0, 1)
)
_BITS = np.array([1, 2, 4], dtype=np.uint8)


@dataclass(frozen=True, slots=True)
class ReferenceResult:
    slopes: np.ndarray  # (N, 3) g12, g23, g13 per mille; NaN where a channel is missing
    votes: np.ndarray  # (N, 3) bool v1, v2, v3
    weights: np.ndarray  # (N, 3) w12, w23, w13
    gradient: np.ndarray  # (N,) per mille; NaN where invalid
    valid: np.ndarray  # (N,) bool: at least one vote passed


def _table_1() -> np.ndarray:
    """(3, 8) weights of each slope value by vote pattern v1 + 2 v2 + 4 v3: the votes a
    value passes in / (2 * passed votes), 0 when none (Table 1), in float64 arithmetic."""
    passed = (np.arange(8)[:, None] >> np.arange(3)) & 1  # (pattern, vote)
    takes_part = passed @ MEMBERSHIP.T
    total = passed.sum(axis=1, keepdims=True)
    w = np.zeros((8, 3), dtype=np.float64)
    np.divide(takes_part, 2 * total, out=w, where=total > 0)
    return np.ascontiguousarray(w.T)


_WEIGHTS = _table_1()


@lru_cache(maxsize=16)
def _pair_constants(
    angles_rad: tuple[float, ...], g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pair (i, j), as (3, 1) columns: cos(theta_i), cos(theta_j), g sin(theta_i - theta_j)."""
    th = np.asarray(angles_rad, dtype=np.float64)
    cos_th = np.cos(th)
    denom = [g * np.sin(th[i] - th[j]) for i, j in PAIRS]
    return cos_th[_PAIR_I, None], cos_th[_PAIR_J, None], np.array(denom)[:, None]


def _slopes(acc: np.ndarray, angles_rad: np.ndarray, g: float) -> np.ndarray:
    """(3, N) slope values of the pairs from channel-major accelerations (3, N).

    In place where it can: on a replay batch every temporary is a megabyte-sized page
    fault, which costs as much as the arithmetic."""
    cos_i, cos_j, denom = _pair_constants(tuple(np.asarray(angles_rad).tolist()), g)
    x = acc[_PAIR_I]
    x *= cos_j
    y = acc[_PAIR_J]
    y *= cos_i
    x -= y
    x /= denom  # cos(alpha) of each pair
    x.clip(-1.0, 1.0, out=x)  # np.clip's ufunc, without its wrappers
    np.arccos(x, out=x)
    np.tan(x, out=x)
    np.multiply(1000.0, x, out=x)
    # an uncomputable value is the one quiet NaN: SIMD arccos may hand back the sign-bit NaN,
    # which a log's JSON null could not give back bit for bit
    np.copyto(x, np.nan, where=np.isnan(x))
    return x


def _votes(slopes: np.ndarray, tolerance_permil: float) -> np.ndarray:
    """(3, N) votes from (3, N) slope values."""
    d = slopes[_VOTE_P]
    d -= slopes[_VOTE_Q]
    votes: np.ndarray = np.abs(d, out=d) <= tolerance_permil
    return votes


def pair_gradients(acc: np.ndarray, angles_rad: np.ndarray, g: float) -> np.ndarray:
    """(N, 3) accelerations (NaN = unusable) -> (N, 3) slope values in per mille.

    cos(alpha_ij) = (a_i cos(theta_j) - a_j cos(theta_i)) / (g sin(theta_i - theta_j)),
    clamped to [-1, 1]; gradient = 1000 tan(alpha_ij), never negative.
    """
    return _slopes(np.asarray(acc, dtype=np.float64).T, angles_rad, g).T


def vote(slopes: np.ndarray, tolerance_permil: float) -> np.ndarray:
    """(N, 3) bool votes; a vote involving an uncomputable (NaN) slope value fails."""
    return _votes(slopes.T, tolerance_permil).T


def weights(votes: np.ndarray) -> np.ndarray:
    """Table 1: a slope value's weight = votes it passes in / (2 * passed votes); 0 when none."""
    return np.take(_WEIGHTS, _pattern(votes.T), axis=1).T


def _pattern(votes: np.ndarray) -> np.ndarray:
    """(N,) vote pattern v1 + 2 v2 + 4 v3 from (3, N) votes."""
    return _BITS @ votes.view(np.uint8)


def fuse(
    acc: np.ndarray, angles_rad: np.ndarray, g: float, tolerance_permil: float
) -> ReferenceResult:
    """The whole reference method over a batch of samples."""
    slopes = _slopes(np.asarray(acc, dtype=np.float64).T, angles_rad, g)
    votes = _votes(slopes, tolerance_permil)
    pattern = _pattern(votes)
    w = np.take(_WEIGHTS, pattern, axis=1)
    # a weighted value passed a vote, so it is finite; the others count as exactly 0.0
    terms = np.multiply(w, slopes)
    np.copyto(terms, 0.0, where=w == 0.0)
    gradient = terms[0] + terms[1]
    gradient += terms[2]
    valid = pattern != 0
    gradient[~valid] = np.nan
    return ReferenceResult(slopes.T, votes.T, w.T, gradient, valid)
