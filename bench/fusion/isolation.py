"""Sensor-level fault isolation: stuck channels, residual outliers, exclusion with hysteresis.

Each stage has a vectorised ``push`` (replay batches) and a scalar ``step`` twin (live
pushes of a sample or two); both carry the same state and apply the same exact rules
(integer ticks, integer fixed-point sums, running maxima), so the decisions do not depend
on how the stream was batched. Tests hold the twins equal. The vectorised stages take
channel-major (3, N) arrays: each channel is then one contiguous row, which is what makes
numpy's running maxima and sums fast (they would run along a stride-3 column otherwise).

Why the residual needs a second criterion: with three channels and two unknowns there is
one parity equation, and an error on any channel shows in it the same way (detection,
not isolation). Isolation uses what the geometry alone cannot: the specific force has
magnitude g. Each pair that leaves one channel out gives its own (u, w); the pair without
the faulty channel satisfies |(u - a_ref, w)| = g, the other two miss it in proportion to
the error. Without a_ref, w = g*cos(alpha) ~ g stands in (good to g*alpha^2/2).
"""

from __future__ import annotations

import math
from collections import deque
from enum import IntEnum

import numpy as np

from bench.fusion.least_squares import PAIR_MASKS, Geometry, Row, combine_arrays
from bench.records.events import EVENT_DTYPE, EventKind, make_events

NEVER = np.iinfo(np.int64).min // 4
"""Tick value meaning "no such event yet" (far in the past, overflow-safe to subtract)."""
FIXED_POINT = 1e9
"""Residual sums are kept in integer units of 1 nm/s^2: exact, so batching cannot change them."""
CLIP_MPS2 = 100.0
ISOLATION_RATIO = 0.5
"""The singled-out pair must miss g by less than half as much as the next best pair."""
_NO_EVENTS = np.zeros(0, dtype=EVENT_DTYPE)


class Reason(IntEnum):
    """Why a channel was excluded: the value of an EXCLUDED event."""

    MISSING = 1  # no frame (lost, or CRC-corrupt): that sample only, no event
    STATUS = 2  # status bits 0..3
    STUCK = 3  # code frozen while the others change
    RESIDUAL = 4  # singled out by the least-squares residual


def _running_last(carried: list[int] | int, ticks: np.ndarray, hit: np.ndarray) -> np.ndarray:
    """Running maximum along the last axis of ``ticks`` where ``hit``, from ``carried``
    (one value per row); without any hit just ``carried``, shaped to broadcast."""
    start = np.asarray(carried, dtype=np.int64)
    if not hit.any():
        return start[..., None]
    stamps = np.where(hit, ticks, NEVER)
    np.maximum(stamps[..., 0], start, out=stamps[..., 0])
    return np.maximum.accumulate(stamps, axis=-1, out=stamps)


# ------------------------------------------------------------------------------ stuck


class StuckDetector:
    """A channel is stuck when its code has not changed for ``window_ticks`` while at least
    one other channel's code changed within that window (so a noise-free board at rest, where
    nothing changes, never counts as stuck). A channel's first appearance counts as a change.
    """

    def __init__(self, window_ticks: int) -> None:
        self.window = window_ticks
        self.code = [0, 0, 0]
        self.seen = [False, False, False]
        self.changed = [int(NEVER)] * 3  # ticks of the last change

    def push(self, ticks: np.ndarray, code: np.ndarray, present: np.ndarray) -> np.ndarray:
        """Stuck flags (3, N) for codes and presence given as (3, N), ticks (N,)."""
        n = len(ticks)
        limit = ticks - self.window  # quiet: last change <= limit, i.e. ticks - it >= window
        quiet = np.empty((3, n), dtype=bool)
        changed = np.empty(n, dtype=bool)
        for k in range(3):  # a channel at a time: (N,) temporaries, not (3, N)
            self._changes(k, code[k], present[k], changed)
            last = _running_last(self.changed[k], ticks, changed)
            self.changed[k] = int(last[-1])
            np.less_equal(last, limit, out=quiet[k])
        if not quiet.any():
            return np.zeros((3, n), dtype=bool)
        busy = ~quiet
        others = np.stack([busy[1] | busy[2], busy[0] | busy[2], busy[0] | busy[1]])
        return present & quiet & others

    def _changes(self, k: int, code: np.ndarray, present: np.ndarray, out: np.ndarray) -> None:
        """Rows where channel k shows a code other than its previous one (or shows first)."""
        if present.all():
            rows, c = None, code
        else:
            rows = np.flatnonzero(present)
            out[:] = False
            if len(rows) == 0:
                return
            c = code[rows]
        chg = out if rows is None else np.empty(len(c), dtype=bool)
        chg[0] = not self.seen[k] or c[0] != self.code[k]
        np.not_equal(c[1:], c[:-1], out=chg[1:])
        if rows is not None:
            out[rows] = chg
        self.code[k] = int(c[-1])
        self.seen[k] = True

    def step(self, ticks: int, code: list[int], present: list[bool]) -> list[bool]:
        changed, seen, last = self.changed, self.seen, self.code
        for k in range(3):
            if present[k]:
                c = code[k]
                if not seen[k] or c != last[k]:
                    changed[k] = ticks
                last[k] = c
                seen[k] = True
        limit = ticks - self.window  # quiet: no change after this
        q0, q1, q2 = changed[0] <= limit, changed[1] <= limit, changed[2] <= limit
        if not (q0 or q1 or q2) or (q0 and q1 and q2):  # none quiet, or none changing
            return [False, False, False]
        return [present[0] and q0, present[1] and q1, present[2] and q2]


# --------------------------------------------------------------------------- residual


def _fixed(v: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Values clipped to +-CLIP_MPS2 in integer nm/s^2 (into ``out`` when given)."""
    x = np.clip(v, -CLIP_MPS2, CLIP_MPS2)
    x *= FIXED_POINT
    np.rint(x, out=x)
    if out is None:
        return x.astype(np.int64)
    out[...] = x  # the same float -> int64 cast as astype
    return out


def _fixed_one(v: float) -> int:
    """Scalar twin of :func:`_fixed` (round() and rint both round half to even)."""
    lim = CLIP_MPS2
    return round((-lim if v < -lim else lim if v > lim else v) * FIXED_POINT)


_EMPTY_ROW = (0, 0, 0, 0, 0)


AMBIGUOUS = -2
"""The isolator's verdict where the residual is beyond its limit but no pair stands out
(a vertical curve's v^2/R, the reference acceleration lagging): one channel is still off."""


def carry_named(single: np.ndarray, cand: np.ndarray, carry: int) -> tuple[np.ndarray, int]:
    """The channel each sample's exclusion reason names (-1: none), and the carry for the
    next batch. While the residual stays beyond its limit with no channel standing out,
    the channel named earlier in the same alarm is still the one off: a drifting channel
    must not be readmitted because a curve made the verdict ambiguous for a moment. A
    sample with three healthy channels and no alarm ends the alarm; one without three
    healthy channels tells nothing and keeps it."""
    sets = (single >= 0) | ((single == -1) & cand)
    idx = np.where(sets, np.arange(len(single)), -1)
    np.maximum.accumulate(idx, out=idx)
    # the last setting sample's verdict (a channel, or -1 where an alarm ended), else carry
    last = np.where(idx >= 0, single[np.maximum(idx, 0)], carry)
    named = np.where(single == AMBIGUOUS, last, single)
    return named, int(last[-1]) if len(last) else carry


def carry_named_one(single: int, cand: bool, carry: int) -> tuple[int, int]:
    """Scalar twin of :func:`carry_named` for one sample: (named, carry)."""
    if single >= 0:
        return single, single
    if single == AMBIGUOUS:
        return carry, carry
    return -1, (-1 if cand else carry)


class ResidualIsolator:
    """Singles out one channel where the moving-mean residual exceeds the limit.

    Moving means over ``window`` samples (those with three healthy channels) of the parity
    residual and of each leave-one-out pair's miss of g. The sums are integers in
    nm/s^2, hence exact whichever way they are formed: cumulative sums over a batch, or a
    running sum sample by sample.
    """

    def __init__(self, geo: Geometry, g: float, limit_mps2: float, window: int) -> None:
        self.geo = geo
        self.g = g
        self.limit = limit_mps2
        self.window = window
        self.pairs: tuple[tuple[Row, Row], ...] = tuple(geo.pinv[m] for m in PAIR_MASKS)
        self._flat_pairs = tuple((*pu, *pw) for pu, pw in self.pairs)
        # (3 pairs, 3 channels, 1): coefficients of each pair's u and w, as columns
        self._pu = np.array([pu for pu, _ in self.pairs])[:, :, None]
        self._pw = np.array([pw for _, pw in self.pairs])[:, :, None]
        # the last window-1 rows (residual, miss1, miss2, miss3, count): a deque of tuples
        # with their running sums for step, or a (5, window-1) array for push (whichever ran
        # last; converted on a switch, which live-to-replay runs make once or never)
        self._tail: deque[tuple[int, ...]] | np.ndarray = np.zeros((5, window - 1), np.int64)
        self._sums = [0, 0, 0, 0, 0]

    def _misses(self, acc: np.ndarray, a_ref: np.ndarray) -> np.ndarray:
        """(3, M) each pair's miss of g for channel-major (3, M) rows ``acc``."""
        a0, a1, a2 = acc[0], acc[1], acc[2]
        pu, pw = self._pu, self._pw
        du = pu[:, 0] * a0 + pu[:, 1] * a1 + pu[:, 2] * a2 - a_ref
        w = pw[:, 0] * a0 + pw[:, 1] * a1 + pw[:, 2] * a2
        return np.where(np.isfinite(a_ref), np.sqrt(du * du + w * w), w) - self.g

    def _tail_array(self) -> np.ndarray:
        if isinstance(self._tail, deque):
            self._tail = np.array(self._tail, dtype=np.int64).reshape(-1, 5).T
        return self._tail

    def push(
        self, acc: np.ndarray, cand: np.ndarray, a_ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(residual per sample, NaN without three healthy channels; channel 0..2 singled
        out per sample, -1 for none, AMBIGUOUS where the residual is beyond the limit but
        no channel stands out) for channel-major ``acc`` (3, N), finite where ``cand``."""
        n, w = len(cand), self.window
        tail = self._tail_array()
        residual = combine_arrays(self.geo.parity, *acc)
        all_cand = bool(cand.all())
        # each row of the window sums is preceded by the tail's columns
        fixed = np.zeros(w - 1 + n, dtype=np.int64)
        fixed[: w - 1] = tail[0]
        if all_cand:
            _fixed(residual, out=fixed[w - 1 :])
        else:
            fixed[w - 1 :][cand] = _fixed(residual[cand])
        if all_cand and tail[4].all():
            count: np.ndarray | int = w  # every window full: the same, without summing
            counted = np.concatenate([tail[4], np.ones(min(n, w - 1), dtype=np.int64)])
        else:
            counted = np.concatenate([tail[4], cand])
            count = np.maximum(_window_sums(counted, w), 1)
        mean = _window_sums(fixed, w) / (count * FIXED_POINT)
        alarm = np.abs(mean, out=mean) > self.limit
        if not all_cand:
            alarm &= cand
        need = bool(alarm.any())
        # the misses of g: for the whole batch when it needs them, else for the rows kept
        lo = 0 if need else max(n - (w - 1), 0)
        misses = np.zeros((3, w - 1 + n - lo), dtype=np.int64)
        misses[:, : w - 1] = tail[1:4]
        sel = np.flatnonzero(cand[lo:])
        if len(sel):
            misses[:, w - 1 + sel] = _fixed(self._misses(acc[:, lo + sel], a_ref[lo + sel]))
        single = np.full(n, -1, dtype=np.int8)
        if need:
            hit_count = count if isinstance(count, int) else count[alarm]
            named = _isolate(_window_sums(misses, w)[:, alarm], hit_count)
            single[alarm] = np.where(named < 0, AMBIGUOUS, named)
        self._tail = np.vstack([fixed[n:], misses[:, n - lo :], counted[len(counted) - (w - 1) :]])
        if not all_cand:
            residual[~cand] = np.nan
        return residual, single

    def step(self, acc: Row, cand: bool, a_ref: float) -> tuple[float, int]:
        """Scalar twin of :meth:`push` (same expressions, same order, so the same floats)."""
        a0, a1, a2 = acc
        p0, p1, p2 = self.geo.parity
        residual = p0 * a0 + p1 * a1 + p2 * a2
        if not cand:
            self._roll(_EMPTY_ROW)
            return math.nan, -1
        g, lim = self.g, CLIP_MPS2
        has_ref = a_ref == a_ref
        misses = []
        for u0, u1, u2, w0, w1, w2 in self._flat_pairs:
            w = w0 * a0 + w1 * a1 + w2 * a2
            if has_ref:
                du = u0 * a0 + u1 * a1 + u2 * a2 - a_ref
                w = math.sqrt(du * du + w * w)
            v = w - g  # _fixed_one, inline: this runs per pair and sample on live runs
            misses.append(round((-lim if v < -lim else lim if v > lim else v) * FIXED_POINT))
        sums = self._roll((_fixed_one(residual), *misses, 1))
        scale = max(sums[4], 1) * FIXED_POINT
        if not abs(sums[0] / scale) > self.limit:
            return residual, -1
        mean_miss = [abs(m) / scale for m in sums[1:4]]
        order = sorted(mean_miss)
        named = order[0] < ISOLATION_RATIO * order[1]
        return residual, mean_miss.index(order[0]) if named else AMBIGUOUS

    def _roll(self, row: tuple[int, ...]) -> list[int]:
        """Window sums including ``row``, which then joins the tail (the oldest row leaves)."""
        tail = self._tail
        if not isinstance(tail, deque):
            tail = self._tail = deque(map(tuple, tail.T.tolist()))
            self._sums = [sum(col) for col in zip(*tail, strict=True)] if tail else [0] * 5
        s = self._sums
        sums = [s[0] + row[0], s[1] + row[1], s[2] + row[2], s[3] + row[3], s[4] + row[4]]
        if self.window > 1:
            tail.append(row)
            o = tail.popleft()
            self._sums = [
                sums[0] - o[0],
                sums[1] - o[1],
                sums[2] - o[2],
                sums[3] - o[3],
                sums[4] - o[4],
            ]
        return sums


def _window_sums(ext: np.ndarray, w: int) -> np.ndarray:
    """Sums of every ``w`` consecutive values along the last axis (integers: exact)."""
    c = np.cumsum(ext, axis=-1)
    n = c.shape[-1] - (w - 1)
    out = np.empty((*c.shape[:-1], n), dtype=c.dtype)
    out[..., 0] = c[..., w - 1]
    np.subtract(c[..., w:], c[..., : n - 1], out=out[..., 1:])
    return out


def _isolate(miss_sums: np.ndarray, count: np.ndarray | int) -> np.ndarray:
    """Channel singled out (or -1) per column of the pairs' (3, M) summed misses of g."""
    mean_miss = np.abs(miss_sums) / (count * FIXED_POINT)
    m0, m1, m2 = mean_miss
    best = np.minimum(np.minimum(m0, m1), m2)
    second = np.maximum(np.minimum(m0, m1), np.minimum(np.maximum(m0, m1), m2))
    return np.where(best < ISOLATION_RATIO * second, np.argmin(mean_miss, axis=0), -1)


# ----------------------------------------------------------------------------- latch


class ExclusionLatch:
    """Excluded from the first bad sample until healthy for ``recover_ticks`` (hysteresis).

    A bad sample is one with a reason (status, stuck, residual); missing data is no
    evidence against the sensor and neither starts nor extends an exclusion.
    """

    def __init__(self, recover_ticks: int) -> None:
        self.recover = recover_ticks
        self.bad = [int(NEVER)] * 3  # ticks of the last bad sample
        self.latched = [False, False, False]

    def push(
        self, ticks: np.ndarray, t: np.ndarray, n: np.ndarray, reason: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(latched (3, N) bool, EXCLUDED/READMITTED events in sample then channel order)
        for ``reason`` (3, N), 0 where the sample is no evidence against the channel."""
        last_bad = _running_last(self.bad, ticks, reason > 0)
        latched = last_bad > ticks - self.recover  # ticks - last_bad < recover
        before = self.latched
        self.bad = last_bad[:, -1].tolist()
        self.latched = latched[:, -1].tolist()
        if not (any(before) or latched.any()):
            return latched, _NO_EVENTS
        flip = np.empty(latched.shape, dtype=bool)
        np.not_equal(latched[:, 0], before, out=flip[:, 0])
        np.not_equal(latched[:, 1:], latched[:, :-1], out=flip[:, 1:])
        row, ch = np.nonzero(flip.T)  # sample-major order
        if len(row) == 0:
            return latched, _NO_EVENTS
        ev = make_events(EventKind.EXCLUDED, t[row], ch + 1, n[row], reason[ch, row])
        ev["kind"] = np.where(latched[ch, row], EventKind.EXCLUDED, EventKind.READMITTED)
        return latched, ev

    def step(
        self, ticks: int, t: float, n: int, reason: list[int]
    ) -> tuple[list[bool], list[tuple]]:
        events = []
        bad, was, recover = self.bad, self.latched, self.recover
        latched = [False, False, False]
        for k in range(3):
            if reason[k] > 0:
                bad[k] = ticks
            now = ticks - bad[k] < recover
            if now != was[k]:
                kind = EventKind.EXCLUDED if now else EventKind.READMITTED
                events.append((t, int(kind), k + 1, n, reason[k]))
                was[k] = now
            latched[k] = now
        return latched, events
