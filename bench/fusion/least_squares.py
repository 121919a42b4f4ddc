"""Least-squares specific force (u, w) from any subset of the three channels (METHOD.md s. 5).

Each channel measures a_i = u*cos(theta_i) + w*sin(theta_i), linear in (u, w), so every
channel subset has a fixed pseudo-inverse: one per 3-bit channel mask, precomputed per
config and applied as ``c0*a0 + c1*a1 + c2*a2`` in that order. Only IEEE-exact element-wise
operations (+ - * / sqrt) are used, so a row gives the same float64 in a batch of any
length, from a live push of one sample to a replay's -- bit for bit.

With all three channels there is one redundant equation. Its parity vector
p = (cos th) x (sin th), normalised, is orthogonal to both columns, so p . a is the signed
length of the least-squares residual vector: zero for consistent channels whatever the
gradient and acceleration, and e * p_k for an error e on channel k.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FULL = 7
"""Mask code with all three channels; code = 1*ch1 + 2*ch2 + 4*ch3."""
PAIR_MASKS = (6, 5, 3)
"""Mask of the pair that leaves out ch1, ch2, ch3 respectively."""
Row = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Geometry:
    pinv: tuple[tuple[Row, Row], ...]  # per mask: (u row, w row); NaN rows below 2 channels
    parity: Row  # unit parity vector
    pinv_array: np.ndarray  # (8, 2, 3), the same numbers for fancy indexing


def geometry(angles_rad: tuple[float, float, float] | np.ndarray) -> Geometry:
    th = np.asarray(angles_rad, dtype=np.float64)
    h = np.column_stack([np.cos(th), np.sin(th)])
    pinv = np.full((8, 2, 3), np.nan)
    for code in range(8):
        used = [k for k in range(3) if code & (1 << k)]
        if len(used) >= 2:
            p = np.zeros((2, 3))
            p[:, used] = np.linalg.pinv(h[used])
            pinv[code] = p
    parity = np.cross(h[:, 0], h[:, 1])
    parity /= np.linalg.norm(parity)
    rows = tuple((tuple(p[0].tolist()), tuple(p[1].tolist())) for p in pinv)
    # tolist() is typed list[Any]: the tuples' lengths (2 rows of 3) are the arrays' shapes
    return Geometry(rows, tuple(parity.tolist()), pinv)  # type: ignore[arg-type]


def mask_code(used: np.ndarray) -> np.ndarray:
    """(3, N) bool, channel-major -> (N,) mask code."""
    return used[0] + 2 * used[1].astype(np.int64) + 4 * used[2].astype(np.int64)


def combine_arrays(c: Row, a0: np.ndarray, a1: np.ndarray, a2: np.ndarray) -> np.ndarray:
    """c0*a0 + c1*a1 + c2*a2 in that order, with few temporaries (on replay batches each
    one is a fresh megabyte of page faults)."""
    out = np.multiply(c[0], a0)
    term = np.multiply(c[1], a1)
    out += term
    out += np.multiply(c[2], a2, out=term)
    return out


def solve(acc: np.ndarray, code: np.ndarray, geo: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """(u, w) per row of ``acc`` (N, 3) from the channels of its mask code (NaN below 2
    channels). ``acc`` must be finite wherever the mask uses it (0 elsewhere)."""
    return solve_channels(acc.T, code, geo)


def solve_channels(
    acc: np.ndarray, code: np.ndarray, geo: Geometry
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`solve` for channel-major ``acc`` (3, N)."""
    table = geo.pinv_array.transpose(1, 2, 0)  # (u/w, channel, code)
    a0, a1, a2 = acc
    cu, cw = np.take(table[0], code, axis=1), np.take(table[1], code, axis=1)
    return cu[0] * a0 + cu[1] * a1 + cu[2] * a2, cw[0] * a0 + cw[1] * a1 + cw[2] * a2


def solve_full(acc: np.ndarray, geo: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """:func:`solve` with all three channels in every sample: the same products of the
    same coefficients, without gathering them per sample."""
    pu, pw = geo.pinv[FULL]
    return combine_arrays(pu, *acc), combine_arrays(pw, *acc)


def magnitude_gradient(w: np.ndarray, g: float) -> np.ndarray:
    """Unsigned 1000 * tan(arccos(w/g)) written as 1000 * sqrt((1-c)(1+c)) / c, c = w/g
    clamped to 1 (noise); NaN unless c > 0. No a_ref needed: the analogue of the reference."""
    c = np.divide(w, g)
    np.minimum(c, 1.0, out=c)
    out = np.subtract(1.0, c)  # in place from here: (1 - c)(1 + c), sqrt, * 1000, / c
    with np.errstate(invalid="ignore", divide="ignore"):
        out *= np.add(1.0, c)
        np.sqrt(out, out=out)
        np.multiply(1000.0, out, out=out)
        np.divide(out, c, out=out)
    np.copyto(out, np.nan, where=~(c > 0.0))
    return out
