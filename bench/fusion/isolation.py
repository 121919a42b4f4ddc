"""Sensor-level fault isolation: stuck channels, residual outliers, exclusion with hysteresis.

Each stage has a vectorised ``push`` (replay batches) and a scalar ``step`` twin (live
pushes of a sample or two); both carry the same state and apply the same exact rules
(integer ticks, integer fixed-point sums, running maxima), so the decisions do not depend
on how the stream was batched. Tests hold the twins equal.

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

from bench.events import EVENT_DTYPE, EventKind, make_events
from bench.fusion.least_squares import PAIR_MASKS, Geometry, Row, combine

NEVER = np.iinfo(np.int64).min // 4
"""Tick value meaning "no such event yet" (far in the past, overflow-safe to subtract)."""
FIXED_POINT = 1e9
"""Residual sums are kept in integer units of 1 nm/s^2: exact, so batching cannot change them."""
CLIP_MPS2 = 100.0
ISOLATION_RATIO = 0.5
"""The singled-out pair must miss g by less than half as much as the next best pair."""


class Reason(IntEnum):
    """Why a channel was excluded: the value of an EXCLUDED event."""

    MISSING = 1  # no frame (lost, or CRC-corrupt): that sample only, no event
    STATUS = 2  # status bits 0..3
    STUCK = 3  # code frozen while the others change
    RESIDUAL = 4  # singled out by the least-squares residual


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
        n = len(ticks)
        rows = np.arange(-1, n)
        codes = np.concatenate([np.array([self.code]), code.astype(np.int64)])
        have = np.concatenate([np.array([self.seen]), present])
        last = np.maximum.accumulate(np.where(have, rows[:, None], -2), axis=0)  # -2: never
        prev = last[:-1]  # last row (-1: carried) with the channel present, before each row
        prev_code = codes[np.maximum(prev + 1, 0), np.arange(3)]
        changed = present & ((prev == -2) | (code != prev_code))
        stamps = np.where(changed, ticks[:, None], NEVER)
        last_change = np.maximum.accumulate(
            np.concatenate([np.array([self.changed]), stamps]), axis=0
        )[1:]
        self.changed = last_change[-1].tolist()
        self.seen = have.any(axis=0).tolist()  # ever seen, not "present in the last row"
        self.code = codes[np.maximum(last[-1] + 1, 0), np.arange(3)].tolist()
        quiet = ticks[:, None] - last_change >= self.window
        active = (~quiet).sum(axis=1, keepdims=True) - ~quiet  # other channels changing
        return present & quiet & (active > 0)

    def step(self, ticks: int, code: list[int], present: list[bool]) -> list[bool]:
        for k in range(3):
            if present[k]:
                if not self.seen[k] or code[k] != self.code[k]:
                    self.changed[k] = ticks
                self.code[k] = code[k]
                self.seen[k] = True
        quiet = [ticks - c >= self.window for c in self.changed]
        n_active = 3 - sum(quiet)
        return [present[k] and quiet[k] and n_active > 0 for k in range(3)]


# --------------------------------------------------------------------------- residual


def _fixed(v: np.ndarray) -> np.ndarray:
    return np.rint(np.clip(v, -CLIP_MPS2, CLIP_MPS2) * FIXED_POINT).astype(np.int64)


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
        # the last window-1 rows: (residual, miss1, miss2, miss3, count), and their sums
        self.tail: deque[tuple[int, int, int, int, int]] = deque([(0, 0, 0, 0, 0)] * (window - 1))
        self.sums = [0, 0, 0, 0, 0]

    def _misses(self, acc: np.ndarray, a_ref: np.ndarray) -> np.ndarray:
        a0, a1, a2 = acc[:, 0], acc[:, 1], acc[:, 2]
        has_ref = np.isfinite(a_ref)
        out = np.empty(acc.shape)
        for k, (pu, pw) in enumerate(self.pairs):
            du = combine(pu, a0, a1, a2) - a_ref
            w = combine(pw, a0, a1, a2)
            out[:, k] = np.where(has_ref, np.sqrt(du * du + w * w), w) - self.g
        return out

    def push(
        self, acc: np.ndarray, cand: np.ndarray, a_ref: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(residual per sample, NaN without three healthy channels; channel 0..2 singled
        out per sample, -1 for none). ``acc`` must be finite where ``cand``."""
        n, w = len(cand), self.window
        residual = combine(self.geo.parity, acc[:, 0], acc[:, 1], acc[:, 2])
        rows = np.zeros((n, 5), dtype=np.int64)
        rows[cand, 0] = _fixed(residual[cand])
        rows[:, 4] = cand
        ext = np.concatenate([np.array(self.tail, dtype=np.int64).reshape(w - 1, 5), rows])
        csum = np.concatenate([np.zeros((1, 2), dtype=np.int64), np.cumsum(ext[:, ::4], axis=0)])
        sums = csum[w:] - csum[:n]
        count = np.maximum(sums[:, 1], 1)
        alarm = cand & (np.abs(sums[:, 0] / (count * FIXED_POINT)) > self.limit)
        # the misses of g: for the whole batch when it needs them, else for the rows kept
        need = bool(alarm.any())
        sel = cand.copy()
        if not need:
            sel[: max(n - (w - 1), 0)] = False
        if sel.any():
            ext[w - 1 :][sel, 1:4] = _fixed(self._misses(acc[sel], a_ref[sel]))
        single = np.full(n, -1, dtype=np.int64)
        if need:
            msum = np.concatenate(
                [np.zeros((1, 3), dtype=np.int64), np.cumsum(ext[:, 1:4], axis=0)]
            )
            hit = np.flatnonzero(alarm)
            mean_miss = np.abs(msum[w:][hit] - msum[hit]) / (count[hit, None] * FIXED_POINT)
            m0, m1, m2 = mean_miss[:, 0], mean_miss[:, 1], mean_miss[:, 2]
            best = np.minimum(np.minimum(m0, m1), m2)
            second = np.maximum(np.minimum(m0, m1), np.minimum(np.maximum(m0, m1), m2))
            ok = best < ISOLATION_RATIO * second
            single[hit[ok]] = np.argmin(mean_miss[ok], axis=1)
        if w > 1:
            kept = ext[-(w - 1) :]
            self.tail = deque(map(tuple, kept.tolist()))
            self.sums = kept.sum(axis=0).tolist()
        residual[~cand] = np.nan
        return residual, single

    def step(self, acc: Row, cand: bool, a_ref: float) -> tuple[float, int]:
        """Scalar twin of :meth:`push` (same expressions, same order, so the same floats)."""
        a0, a1, a2 = acc
        p0, p1, p2 = self.geo.parity
        residual = p0 * a0 + p1 * a1 + p2 * a2
        if not cand:
            row: tuple[int, ...] = (0, 0, 0, 0, 0)
        else:
            g, lim = self.g, CLIP_MPS2
            has_ref = a_ref == a_ref
            vals = [residual]
            for (u0, u1, u2), (w0, w1, w2) in self.pairs:
                w = w0 * a0 + w1 * a1 + w2 * a2
                if has_ref:
                    du = u0 * a0 + u1 * a1 + u2 * a2 - a_ref
                    w = math.sqrt(du * du + w * w)
                vals.append(w - g)
            row = (*(round(min(max(v, -lim), lim) * FIXED_POINT) for v in vals), 1)
        s0, s1, s2, s3, s4 = self.sums
        r0, r1, r2, r3, r4 = row
        sums = (s0 + r0, s1 + r1, s2 + r2, s3 + r3, s4 + r4)
        if self.window > 1:
            self.tail.append(row)
            o0, o1, o2, o3, o4 = self.tail.popleft()
            self.sums = [sums[0] - o0, sums[1] - o1, sums[2] - o2, sums[3] - o3, sums[4] - o4]
        if not cand:
            return math.nan, -1
        scale = max(sums[4], 1) * FIXED_POINT
        if not abs(sums[0] / scale) > self.limit:
            return residual, -1
        mean_miss = [abs(m) / scale for m in sums[1:4]]
        order = sorted(mean_miss)
        return residual, mean_miss.index(order[0]) if order[0] < ISOLATION_RATIO * order[1] else -1


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
        """(latched (N, 3) bool, EXCLUDED/READMITTED events in sample then channel order)."""
        stamps = np.where(reason > 0, ticks[:, None], NEVER)
        last_bad = np.maximum.accumulate(np.concatenate([np.array([self.bad]), stamps]), axis=0)[1:]
        latched = (ticks[:, None] - last_bad) < self.recover
        prev = np.concatenate([np.array([self.latched]), latched[:-1]])
        self.bad = last_bad[-1].tolist()
        self.latched = latched[-1].tolist()
        row, ch = np.nonzero(latched != prev)
        if len(row) == 0:
            return latched, np.zeros(0, dtype=EVENT_DTYPE)
        ev = make_events(EventKind.EXCLUDED, t[row], ch + 1, n[row], reason[row, ch])
        ev["kind"] = np.where(latched[row, ch], EventKind.EXCLUDED, EventKind.READMITTED)
        return latched, ev

    def step(
        self, ticks: int, t: float, n: int, reason: list[int]
    ) -> tuple[list[bool], list[tuple]]:
        events = []
        latched = []
        for k in range(3):
            if reason[k] > 0:
                self.bad[k] = ticks
            now = ticks - self.bad[k] < self.recover
            if now != self.latched[k]:
                kind = EventKind.EXCLUDED if now else EventKind.READMITTED
                events.append((t, int(kind), k + 1, n, reason[k]))
            self.latched[k] = now
            latched.append(now)
        return latched, events
