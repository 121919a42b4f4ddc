"""Sensor-level fault isolation: stuck channels, residual outliers, exclusion with hysteresis.

Each stage's ``push`` runs one loop compiled by numba (no fastmath: IEEE arithmetic in the
order written) over a batch of any length, from a live sample to a replay's million, and
carries its state between pushes in small arrays. The rules are exact (integer ticks,
integer fixed-point sums), so the decisions do not depend on how the stream was batched.
The stages take channel-major (3, N) arrays, as the estimator holds them.

Why the residual needs a second criterion: with three channels and two unknowns there is
one parity equation, and an error on any channel shows in it the same way (detection,
not isolation). Isolation uses what the geometry alone cannot: the specific force has
magnitude g. Each pair that leaves one channel out gives its own (u, w); the pair without
the faulty channel satisfies |(u - a_ref, w)| = g, the other two miss it in proportion to
the error. Without a_ref, w = g*cos(alpha) ~ g stands in (good to g*alpha^2/2).
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np
from numba import njit

from bench.fusion.least_squares import PAIR_MASKS, Geometry
from bench.records.events import EVENT_DTYPE, EventKind, make_events

NEVER = np.iinfo(np.int64).min // 4
"""Tick value meaning "no such event yet" (far in the past, overflow-safe to subtract)."""
FIXED_POINT = 1e9
"""Residual sums are kept in integer units of 1 nm/s^2: exact, so batching cannot change them."""
CLIP_MPS2 = 100.0
ISOLATION_RATIO = 0.5
"""The singled-out pair must miss g by less than half as much as the next best pair."""
AMBIGUOUS = -2
"""The isolator's verdict where the residual is beyond its limit but no pair stands out
(a vertical curve's v^2/R, the reference acceleration lagging): one channel is still off."""
_NO_EVENTS = np.zeros(0, dtype=EVENT_DTYPE)
_I8, _I64, _F8, _B = np.int8, np.int64, np.float64, np.bool_


class Reason(IntEnum):
    """Why a channel was excluded: the value of an EXCLUDED event."""

    MISSING = 1  # no frame (lost, or CRC-corrupt): that sample only, no event
    STATUS = 2  # status bits 0..3
    STUCK = 3  # code frozen while the others change
    RESIDUAL = 4  # singled out by the least-squares residual


_EMPTY_I8, _EMPTY_I64, _EMPTY_F8, _EMPTY_B = (np.zeros(0, d) for d in (_I8, _I64, _F8, _B))
_EMPTY_3I64, _EMPTY_3F8, _EMPTY_3B = (np.zeros((3, 0), d) for d in (_I64, _F8, _B))


def _arr(x: np.ndarray, dtype: type) -> np.ndarray:
    """Contiguous in the dtype the kernels are compiled for (no copy when it already is)."""
    return np.ascontiguousarray(x, dtype=dtype)


# ------------------------------------------------------------------------------ stuck


@njit(cache=True)
def _stuck_run(window, last, seen, changed, ticks, code, present, out):  # type: ignore[no-untyped-def]
    for i in range(len(ticks)):
        tk = ticks[i]
        for k in range(3):
            if present[k, i]:
                if not seen[k] or code[k, i] != last[k]:
                    changed[k] = tk
                last[k] = code[k, i]
                seen[k] = True
        limit = tk - window  # quiet: no change after this
        q0, q1, q2 = changed[0] <= limit, changed[1] <= limit, changed[2] <= limit
        some = (q0 or q1 or q2) and not (q0 and q1 and q2)  # one quiet while another changes
        out[0, i] = some and q0 and present[0, i]
        out[1, i] = some and q1 and present[1, i]
        out[2, i] = some and q2 and present[2, i]


class StuckDetector:
    """A channel is stuck when its code has not changed for ``window_ticks`` while at least
    one other channel's code changed within that window (so a noise-free board at rest, where
    nothing changes, never counts as stuck). A channel's first appearance counts as a change.
    """

    def __init__(self, window_ticks: int) -> None:
        self.window = window_ticks
        self.code = np.zeros(3, _I64)  # the last code seen
        self.seen = np.zeros(3, _B)
        self.changed = np.full(3, NEVER, _I64)  # ticks of the last change
        self.push(_EMPTY_I64, _EMPTY_3I64, _EMPTY_3B)  # compile or load now, not live

    def push(self, ticks: np.ndarray, code: np.ndarray, present: np.ndarray) -> np.ndarray:
        """Stuck flags (3, N) for codes and presence given as (3, N), ticks (N,)."""
        out = np.empty((3, len(ticks)), _B)
        _stuck_run(
            self.window, self.code, self.seen, self.changed,
            _arr(ticks, _I64), _arr(code, _I64), _arr(present, _B), out,
        )  # fmt: skip
        return out


# --------------------------------------------------------------------------- residual


@njit(cache=True)
def _carry_run(single, cand, carry, named):  # type: ignore[no-untyped-def]
    for i in range(len(single)):
        s = single[i]
        if s >= 0:
            carry = s
        elif s == -1 and cand[i]:
            carry = -1
        named[i] = carry if s == AMBIGUOUS else s
    return carry


def carry_named(single: np.ndarray, cand: np.ndarray, carry: int) -> tuple[np.ndarray, int]:
    """The channel each sample's exclusion reason names (-1: none), and the carry for the
    next batch. While the residual stays beyond its limit with no channel standing out,
    the channel named earlier in the same alarm is still the one off: a drifting channel
    must not be readmitted because a curve made the verdict ambiguous for a moment. A
    sample with three healthy channels and no alarm ends the alarm; one without three
    healthy channels tells nothing and keeps it."""
    named = np.empty(len(single), _I8)
    carry = _carry_run(_arr(single, _I8), _arr(cand, _B), carry, named)
    return named, int(carry)


@njit(cache=True)
def _fixed(v):  # type: ignore[no-untyped-def]
    """A value clipped to +-CLIP_MPS2 in integer nm/s^2 (rint: half to even)."""
    if v < -CLIP_MPS2:
        v = -CLIP_MPS2
    elif v > CLIP_MPS2:
        v = CLIP_MPS2
    return np.int64(np.rint(v * FIXED_POINT))


@njit(cache=True)
def _residual_run(  # type: ignore[no-untyped-def]
    parity, pu, pw, g, limit, tail, pos, sums, acc, cand, a_ref, residual, single
):
    """One sample at a time: the window sums are those of the last ``window - 1`` rows (the
    ring ``tail``, next slot ``pos[0]``, their sums ``sums``) plus this sample's row."""
    slots = tail.shape[1]
    row = np.zeros(5, np.int64)
    for i in range(len(cand)):
        a0, a1, a2 = acc[0, i], acc[1, i], acc[2, i]
        r = parity[0] * a0 + parity[1] * a1 + parity[2] * a2
        single[i] = -1
        if cand[i]:
            residual[i] = r
            row[0] = _fixed(r)
            for p in range(3):
                w = pw[p, 0] * a0 + pw[p, 1] * a1 + pw[p, 2] * a2
                if math.isfinite(a_ref[i]):
                    du = pu[p, 0] * a0 + pu[p, 1] * a1 + pu[p, 2] * a2 - a_ref[i]
                    w = math.sqrt(du * du + w * w)
                row[1 + p] = _fixed(w - g)
            row[4] = 1
        else:
            residual[i] = math.nan
            row[:] = 0
        s0, s4 = sums[0] + row[0], sums[4] + row[4]
        scale = max(s4, 1) * FIXED_POINT
        if cand[i] and abs(s0 / scale) > limit:
            m0 = abs(sums[1] + row[1]) / scale
            m1 = abs(sums[2] + row[2]) / scale
            m2 = abs(sums[3] + row[3]) / scale
            best = min(min(m0, m1), m2)
            second = max(min(m0, m1), min(max(m0, m1), m2))
            if best < ISOLATION_RATIO * second:
                single[i] = 0 if m0 == best else 1 if m1 == best else 2
            else:
                single[i] = AMBIGUOUS
        if slots:  # the row joins the ring, the oldest leaves it
            j = pos[0]
            for c in range(5):
                sums[c] += row[c] - tail[c, j]
                tail[c, j] = row[c]
            pos[0] = j + 1 if j + 1 < slots else 0


class ResidualIsolator:
    """Singles out one channel where the moving-mean residual exceeds the limit.

    Moving means over ``window`` samples (those with three healthy channels) of the parity
    residual and of each leave-one-out pair's miss of g. The sums are integers in
    nm/s^2, hence exact however the stream is cut.
    """

    def __init__(self, geo: Geometry, g: float, limit_mps2: float, window: int) -> None:
        self.geo = geo
        self.g = g
        self.limit = limit_mps2
        self.window = window
        self._parity = np.array(geo.parity)
        # (3 pairs, 3 channels): coefficients of each pair's u and w
        self._pu = np.ascontiguousarray(geo.pinv_array[list(PAIR_MASKS), 0])
        self._pw = np.ascontiguousarray(geo.pinv_array[list(PAIR_MASKS), 1])
        # the last window-1 rows (residual, miss1, miss2, miss3, count), a ring of columns
        self._tail = np.zeros((5, window - 1), _I64)
        self._pos = np.zeros(1, _I64)
        self._sums = np.zeros(5, _I64)
        self.push(_EMPTY_3F8, _EMPTY_B, _EMPTY_F8)  # compile or load now, not live
        carry_named(_EMPTY_I8, _EMPTY_B, -1)

    def push(
        self, acc: np.ndarray, cand: np.ndarray, a_ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(residual per sample, NaN without three healthy channels; channel 0..2 singled
        out per sample, -1 for none, AMBIGUOUS where the residual is beyond the limit but
        no channel stands out) for channel-major ``acc`` (3, N), finite where ``cand``."""
        n = len(cand)
        residual, single = np.empty(n), np.empty(n, _I8)
        _residual_run(
            self._parity, self._pu, self._pw, self.g, self.limit,
            self._tail, self._pos, self._sums,
            _arr(acc, _F8), _arr(cand, _B), _arr(a_ref, _F8), residual, single,
        )  # fmt: skip
        return residual, single


# ----------------------------------------------------------------------------- latch


@njit(cache=True)
def _latch_run(recover, bad, was, ticks, reason, latched, flips):  # type: ignore[no-untyped-def]
    """Latched flags per channel and sample; the (sample, channel) of each flip into
    ``flips`` (sample then channel order); returns their count."""
    nflip = 0
    for i in range(len(ticks)):
        for k in range(3):
            if reason[k, i] > 0:
                bad[k] = ticks[i]
            now = ticks[i] - bad[k] < recover
            latched[k, i] = now
            if now != was[k]:
                flips[nflip, 0] = i
                flips[nflip, 1] = k
                nflip += 1
                was[k] = now
    return nflip


class ExclusionLatch:
    """Excluded from the first bad sample until healthy for ``recover_ticks`` (hysteresis).

    A bad sample is one with a reason (status, stuck, residual); missing data is no
    evidence against the sensor and neither starts nor extends an exclusion.
    """

    def __init__(self, recover_ticks: int) -> None:
        self.recover = recover_ticks
        self.bad = np.full(3, NEVER, _I64)  # ticks of the last bad sample
        self.latched = np.zeros(3, _B)
        self.push(_EMPTY_I64, _EMPTY_F8, _EMPTY_I64, _EMPTY_3I64)  # compile or load now

    def push(
        self, ticks: np.ndarray, t: np.ndarray, n: np.ndarray, reason: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(latched (3, N) bool, EXCLUDED/READMITTED events in sample then channel order)
        for ``reason`` (3, N), 0 where the sample is no evidence against the channel."""
        reason = _arr(reason, _I64)
        latched = np.empty(reason.shape, _B)
        flips = np.empty((3 * len(ticks), 2), _I64)
        nflip = _latch_run(
            self.recover, self.bad, self.latched, _arr(ticks, _I64), reason, latched, flips
        )
        if nflip == 0:
            return latched, _NO_EVENTS
        row, ch = flips[:nflip, 0], flips[:nflip, 1]
        ev = make_events(EventKind.EXCLUDED, t[row], ch + 1, n[row], reason[ch, row])
        ev["kind"] = np.where(latched[ch, row], EventKind.EXCLUDED, EventKind.READMITTED)
        return latched, ev


KERNELS = (_stuck_run, _carry_run, _residual_run, _latch_run)
"""The compiled loops of this module (each stage's constructor compiles or loads its own)."""
