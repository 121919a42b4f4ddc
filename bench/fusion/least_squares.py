"""Least-squares specific force (u, w) from any subset of the three channels (METHOD.md s. 5).

Each channel measures a_i = u*cos(theta_i) + w*sin(theta_i), linear in (u, w), so every
channel subset has a fixed pseudo-inverse: one per 3-bit channel mask, precomputed per
config and applied as ``c0*a0 + c1*a1 + c2*a2`` in that order, by one compiled loop (numba,
no fastmath). Only IEEE-exact element-wise operations (+ - * / sqrt) are used, so a row
gives the same float64 in a batch of any length, from a live push of one sample to a
replay's -- bit for bit.

With all three channels there is one redundant equation. Its parity vector
p = (cos th) x (sin th), normalised, is orthogonal to both columns, so p . a is the signed
length of the least-squares residual vector: zero for consistent channels whatever the
gradient and acceleration, and e * p_k for an error e on channel k.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

FULL = 7
"""Mask code with all three channels; code = 1*ch1 + 2*ch2 + 4*ch3."""
PAIR_MASKS = (6, 5, 3)
"""Mask of the pair that leaves out ch1, ch2, ch3 respectively."""
Row = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Geometry:
    parity: Row  # unit parity vector
    pinv_array: np.ndarray  # (8, 2, 3): per mask, (u row, w row); NaN rows below 2 channels


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
    # tolist() is typed list[Any]: the tuple's length (3) is the array's
    return Geometry(tuple(parity.tolist()), pinv)  # type: ignore[arg-type]


def mask_code(used: np.ndarray) -> np.ndarray:
    """(3, N) bool, channel-major -> (N,) mask code."""
    return used[0] + 2 * used[1].astype(np.int64) + 4 * used[2].astype(np.int64)


@njit(cache=True)
def _solve_run(pinv, g, acc, code, u, w, magnitude):  # type: ignore[no-untyped-def]
    for i in range(len(code)):
        c = code[i]
        a0 = acc[0, i] if c & 1 else 0.0  # a channel the mask leaves out counts as 0
        a1 = acc[1, i] if c & 2 else 0.0
        a2 = acc[2, i] if c & 4 else 0.0
        u[i] = pinv[c, 0, 0] * a0 + pinv[c, 0, 1] * a1 + pinv[c, 0, 2] * a2
        w[i] = pinv[c, 1, 0] * a0 + pinv[c, 1, 1] * a1 + pinv[c, 1, 2] * a2
        x = w[i] / g
        if x > 1.0:  # noise: clamped (NaN stays NaN)
            x = 1.0
        magnitude[i] = 1000.0 * math.sqrt((1.0 - x) * (1.0 + x)) / x if x > 0.0 else math.nan


def solve_channels(
    acc: np.ndarray, code: np.ndarray, geo: Geometry, g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, w) per sample of channel-major ``acc`` (3, N) from the channels of its mask code
    (NaN below 2 channels), and the unsigned magnitude gradient 1000 tan(arccos(w/g)),
    written as 1000 sqrt((1-c)(1+c)) / c with c = w/g clamped to 1 (noise), NaN unless
    c > 0: no a_ref needed, the analogue of the reference method."""
    n = len(code)
    u, w, magnitude = np.empty(n), np.empty(n), np.empty(n)
    _solve_run(
        geo.pinv_array, g, np.ascontiguousarray(acc, dtype=np.float64),
        np.ascontiguousarray(code, dtype=np.int64), u, w, magnitude,
    )  # fmt: skip
    return u, w, magnitude


def solve(acc: np.ndarray, code: np.ndarray, geo: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """(u, w) per row of ``acc`` (N, 3) from the channels of its mask code (NaN below 2
    channels; the channels it leaves out are not read)."""
    u, w, _ = solve_channels(np.asarray(acc).T, code, geo, 1.0)
    return u, w


KERNELS = (_solve_run,)
"""The compiled loop of this module (the estimator's constructor compiles or loads it)."""
