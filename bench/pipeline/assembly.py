"""Sample assembly: group the three channel frames of one sampling instant.

One algorithm serves live runs (batches of a few frames) and replay (batches of a
million): it carries its state across batches, and the outcome does not depend on how the
stream is cut into batches (tests prove it). One numpy path serves a live step of one
frame and a log's batch of 65 536. The state between batches is small Python values (at
most WINDOW open samples).

The rules, all driven by frame contents and order (never by wall-clock time), so a live
run and the replay of its log decide alike:

* Unwrapping. Each valid ADC frame gets an unwrapped sample index ``n`` relative to the
  previous placed ADC frame from the board-timestamp step (``bench.pipeline.timeline``: receive
  time only bridges 6.5536 s wraps, and only when its gap is whole wraps; a lone frame
  with a wild receive or board time is an outlier, a clock step a notice). Once a
  BOARD_STATUS frame has given the sample rate, board time places the frame and a
  counter that disagrees is reported (COUNTER_JUMP, per frame and channel), so one
  channel's bad counter cannot pull the others apart. Before that, the counter (mod 256)
  corrects the predicted step. Counter wrap 255 -> 0 never splits a sample and long gaps
  do not alias.
* Membership. A frame joins sample ``n`` unless it is *late* (some earlier frame already
  reached ``n + WINDOW``: the sample was closed) or a *duplicate* (its channel already
  joined ``n``). Late and duplicate frames are counted and ignored.
* Emission. A sample is emitted when closed (overdue: the stream reached ``n + WINDOW``)
  or, earlier, when all three channels are in and every earlier sample is out. Output is
  always in ``n`` order. A closed sample proceeds without its missing channels.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.pipeline.timeline import (
    RX_TOL_TICKS,
    WINDOW,
    Note,
    Timeline,
    vector_steps,
)
from bench.records.events import EVENT_DTYPE, NO_EVENTS, EventKind, concat_events, make_events
from bench.records.samples import NO_SAMPLES, SAMPLE_DTYPE
from protocol.batch import DecodedBatch
from protocol.layout import STATUS_FAULT_MASK, TICK_S, FrameKind, Outcome

_NONE = np.iinfo(np.int64).min // 4
_ADC, _STATUS, _OK = int(FrameKind.ADC), int(FrameKind.STATUS), int(Outcome.OK)
_ERRORS = (
    (int(Outcome.CRC_MISMATCH), EventKind.CRC_ERROR, "can_id"),
    (int(Outcome.WRONG_DLC), EventKind.WRONG_DLC, "dlc"),
    (int(Outcome.UNKNOWN_ID), EventKind.UNKNOWN_ID, "can_id"),
)
_COUNTER_JUMP, _LATE, _DUPLICATE = (
    int(EventKind.COUNTER_JUMP),
    int(EventKind.LATE),
    int(EventKind.DUPLICATE),
)
_STATUS_FLAG, _GAP, _SAMPLES_LOST = (
    int(EventKind.STATUS_FLAG),
    int(EventKind.GAP),
    int(EventKind.SAMPLES_LOST),
)

Row = list[Any]
"""An open sample: [n, ticks, t, seq, code[3], status[3], present[3]] (SAMPLE_DTYPE order)."""


def _rows_to_array(rows: list[Row]) -> np.ndarray:
    if not rows:
        return NO_SAMPLES
    return np.array([tuple(r) for r in rows], dtype=SAMPLE_DTYPE)


def _array_to_rows(samples: np.ndarray) -> list[Row]:
    return [
        list(r)
        for r in zip(
            samples["n"].tolist(),
            samples["ticks"].tolist(),
            samples["t"].tolist(),
            samples["seq"].tolist(),
            samples["code"].tolist(),
            samples["status"].tolist(),
            samples["present"].tolist(),
            strict=True,
        )
    ]


def _notes_array(notes: list[Note]) -> np.ndarray:
    """The timeline's events (already in EVENT_DTYPE field order)."""
    return np.array(notes, dtype=EVENT_DTYPE) if notes else NO_EVENTS


def _isin(a: np.ndarray, b: list[int]) -> np.ndarray:
    """np.isin for the few keys of the open samples: only keys up to max(b) can match."""
    hit = np.zeros(len(a), dtype=bool)
    if not b:
        return hit
    cand = np.flatnonzero(a <= max(b))
    if len(cand):
        members = set(b)
        hit[cand] = [x in members for x in a[cand].tolist()]
    return hit


def _first_of_each(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique values, index of each one's first occurrence); O(N) when ``a`` is sorted,
    as it is for an in-order stream, else np.unique's sort."""
    if len(a) == 0:
        return a, np.zeros(0, dtype=np.intp)
    if len(a) < 2 or bool(np.all(a[1:] >= a[:-1])):
        first = np.flatnonzero(np.concatenate(([True], a[1:] != a[:-1])))
        return a[first], first
    return np.unique(a, return_index=True)


def _shifted(a: np.ndarray, first: object) -> np.ndarray:
    """``a`` moved one place right, ``first`` in front: each element's predecessor."""
    out = np.empty_like(a)
    out[0] = first
    out[1:] = a[:-1]
    return out


class Assembler:
    """Stateful sample assembly (see module docstring for the rules)."""

    def __init__(self, sample_rate_hz: float) -> None:
        self.period_ticks = 1.0 / (sample_rate_hz * TICK_S)
        self.rate_known = False  # set once a BOARD_STATUS frame has told us the rate
        self.timeline = Timeline()  # where frames go: chain of the last placed ADC frame
        self.max_n = _NONE
        self.last_emitted: int | None = None
        self._last_row_n: int | None = None
        self._open: list[Row] = []  # samples still open, in n order (at most WINDOW)
        self._recent: list[int] = []  # n of complete samples emitted early, within the window

    # -- main entry ----------------------------------------------------------------------
    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """End of stream: emit every open sample as it is."""
        rows, self._open = self._open, []
        if rows:
            self.last_emitted = rows[-1][0]
        notes = _notes_array(self.timeline.finish())
        out = _rows_to_array(rows)
        return out, concat_events([notes, self._gap_events(out)])

    # -- shared --------------------------------------------------------------------------
    def _accepted_keys(self) -> list[int]:
        """Keys n * 4 + channel already taken: open samples and early-emitted ones."""
        keys = [r[0] * 4 + k + 1 for r in self._open for k in range(3) if r[6][k]]
        keys += [m * 4 + k for m in self._recent for k in (1, 2, 3)]
        return keys

    def _error_events(self, t: np.ndarray, dec: DecodedBatch) -> np.ndarray:
        if not dec.outcome.any():
            return NO_EVENTS
        parts = []
        for outcome, kind, field in _ERRORS:
            idx = np.flatnonzero(dec.outcome == outcome)
            if len(idx):
                value = getattr(dec, field)
                parts.append(make_events(kind, t[idx], dec.channel[idx], -1, value[idx]))
        return concat_events(parts)

    def _emit_rows(self, rows: list[Row]) -> list[Row]:
        """Take the emitted samples off ``rows`` (all open samples, in n order); the rest
        stay open. Closed ones go, then complete ones that follow the last emitted."""
        bound = self.max_n - WINDOW
        i = 0
        while i < len(rows) and rows[i][0] <= bound:
            i += 1
        last = bound if self.last_emitted is None else max(self.last_emitted, bound)
        k = i
        while k < len(rows) and rows[k][0] == last + 1 and all(rows[k][6]):
            last += 1
            k += 1
        self.last_emitted = last
        self._recent = [m for m in self._recent if m > bound]
        self._recent += [r[0] for r in rows[i:k]]
        self._open = rows[k:]
        return rows[:k]

    # -- placement, membership, merge and emission, for any batch length -----------------
    def _periods(
        self, dec: DecodedBatch, adc_idx: np.ndarray
    ) -> tuple[float | np.ndarray, bool | np.ndarray]:
        """Period (ticks) in force at each ADC frame, and whether a status frame set it;
        plain scalars when the batch's status frames change neither (the usual case)."""
        st = np.flatnonzero((dec.kind == _STATUS) & (dec.outcome == _OK) & (dec.sample_rate > 0))
        if len(st) == 0:
            return self.period_ticks, self.rate_known
        rates = dec.sample_rate[st].astype(np.float64)
        periods = 1.0 / (rates * TICK_S)
        before = self.period_ticks, self.rate_known
        self.period_ticks = float(periods[-1])
        self.rate_known = True
        if before[1] and bool(np.all(periods == before[0])):
            return before[0], True
        period = np.full(len(adc_idx), before[0])
        known = np.full(len(adc_idx), before[1])
        j = np.searchsorted(st, adc_idx) - 1
        has = j >= 0
        period[has] = periods[j[has]]
        known[has] = True
        return period, known

    def push(
        self, t: np.ndarray, dec: DecodedBatch, seq0: int = 0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Feed frames (receive times + decoded batch; ``seq0`` = arrival index of the first).

        Returns (emitted samples, events)."""
        events = [self._error_events(t, dec)]
        adc: np.ndarray = np.flatnonzero((dec.kind == _ADC) & (dec.outcome == _OK))
        period, known = self._periods(dec, adc)
        if len(adc) == 0:
            return NO_SAMPLES, concat_events(events)

        c = dec.counter[adc]
        ts = dec.timestamp[adc]
        tt: np.ndarray = np.asarray(t[adc], dtype=np.float64)
        ch: np.ndarray = dec.channel[adc].astype(np.int64)
        n, big_t, keep, tt = self._place_vector(tt, ts, c, ch, period, known)
        if keep is not None:  # outliers leave the stream here (their events are raised)
            sel = np.flatnonzero(keep)
            c, tt, ch, adc, n, big_t = (a[sel] for a in (c, tt, ch, adc, n, big_t))
            if not isinstance(known, bool):
                known = known[sel]
        if self.timeline.notes:
            events.append(_notes_array(self.timeline.take_notes()))

        # counter vs. the placed index, mod 256 (int8 wrap = centred remainder)
        mismatch = (c - n.astype(np.uint8)).view(np.int8)
        jump = (mismatch != 0) & known
        if jump.any():
            events.append(
                make_events(EventKind.COUNTER_JUMP, tt[jump], ch[jump], n[jump], mismatch[jump])
            )

        if len(n) == 0:
            return NO_SAMPLES, concat_events(events)
        acc, late = self._membership(n, ch)
        dup = ~late & ~acc
        any_late, any_dup = bool(late.any()), bool(dup.any())
        if any_late:
            events.append(make_events(EventKind.LATE, tt[late], ch[late], n[late]))
        if any_dup:
            events.append(make_events(EventKind.DUPLICATE, tt[dup], ch[dup], n[dup]))
        status = dec.status[adc]
        flagged = acc & ((status & STATUS_FAULT_MASK) != 0)
        if flagged.any():
            events.append(
                make_events(
                    EventKind.STATUS_FLAG, tt[flagged], ch[flagged], n[flagged], status[flagged]
                )
            )
        if any_late or any_dup:  # else every frame was accepted: no gathers needed
            sel = np.flatnonzero(acc)
            n, ch, status, big_t, tt, adc = (a[sel] for a in (n, ch, status, big_t, tt, adc))
        table = self._merge(n, ch, dec.code[adc], status, big_t, tt, seq0 + adc)
        out = self._emit_table(table)
        events.append(self._gap_events(out))
        return out, concat_events(events)

    def _place_vector(
        self,
        tt: np.ndarray,
        ts: np.ndarray,
        c: np.ndarray,
        ch: np.ndarray,
        period: float | np.ndarray,
        known: bool | np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
        """(n, T, kept or None for all, receive times for the samples) of each ADC frame.

        The fast check (a frame against its predecessor), on every frame at
        once; the few frames it does not pass (and the frame after a suspect one) go
        through Timeline.slow one by one, the runs between them by cumulative sums."""
        timeline = self.timeline
        if timeline.chain is None:
            timeline.start(float(tt[0]), int(ts[0]), int(c[0]))
        assert timeline.chain is not None  # started just above
        t0, ts0, big_t0, c0, n0 = timeline.chain
        d = (ts - _shifted(ts, ts0)).view(np.int16).astype(np.int64)  # centred, mod 2**16
        c_prev = _shifted(c, c0)
        step = vector_steps(d, c, c_prev, period, known)
        with np.errstate(invalid="ignore", over="ignore"):
            fast = np.abs((tt - _shifted(tt, t0)) / TICK_S - d) <= RX_TOL_TICKS
        counter_ok = (c - c_prev - step.astype(np.uint8)) == 0
        fast &= (np.abs(step) <= WINDOW) | counter_ok
        if timeline.pending is not None:
            fast[0] = False
        if bool(fast.all()):
            n = np.cumsum(step) + n0
            big_t = np.cumsum(d) + big_t0
            timeline.chain = (float(tt[-1]), int(ts[-1]), int(big_t[-1]), int(c[-1]), int(n[-1]))
            return n, big_t, None, tt
        n = np.empty(len(tt), dtype=np.int64)
        big_t = np.empty(len(tt), dtype=np.int64)
        keep = np.ones(len(tt), dtype=bool)
        tt = tt.copy()
        slow = np.flatnonzero(~fast).tolist()
        mx, pos, k = self.max_n, 0, 0
        while True:
            if timeline.pending is not None:
                i = pos
            else:
                while k < len(slow) and slow[k] < pos:
                    k += 1
                i = slow[k] if k < len(slow) else len(tt)
            if i > pos:  # a run of fast frames after the chain
                chain = timeline.chain
                assert chain is not None
                n[pos:i] = np.cumsum(step[pos:i]) + chain[4]
                big_t[pos:i] = np.cumsum(d[pos:i]) + chain[2]
                mx = max(mx, int(n[pos:i].max()))
                j = i - 1
                timeline.chain = (float(tt[j]), int(ts[j]), int(big_t[j]), int(c[j]), int(n[j]))
            if i >= len(tt):
                break
            per = period if isinstance(period, float) else float(period[i])
            kn = known if isinstance(known, bool) else bool(known[i])
            where = timeline.slow(float(tt[i]), int(ts[i]), int(c[i]), int(ch[i]), per, kn, mx)
            if where is None:
                keep[i] = False
                n[i] = big_t[i] = 0
            else:
                n[i], big_t[i], tt[i] = where
                mx = max(mx, where[0])
            pos = i + 1
        return n, big_t, (None if bool(keep.all()) else keep), tt

    def _membership(self, n: np.ndarray, ch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(accepted, late) per ADC frame; updates max_n."""
        running = np.maximum.accumulate(n)
        np.maximum(running, self.max_n, out=running)
        late = _shifted(running, self.max_n) >= n + WINDOW
        self.max_n = int(running[-1])
        key = n * 4 + ch
        fresh = ~late
        taken = self._accepted_keys()
        if taken:
            fresh &= ~_isin(key, taken)
        idx = np.flatnonzero(fresh)
        kf = key[idx]
        if len(kf) > 1 and not bool(np.all(kf[1:] > kf[:-1])):  # else all distinct
            _, first = _first_of_each(kf)
            idx = idx[first]
            fresh = np.zeros(len(n), dtype=bool)
            fresh[idx] = True
        return fresh, late

    def _merge(
        self,
        n: np.ndarray,
        ch: np.ndarray,
        code: np.ndarray,
        status: np.ndarray,
        big_t: np.ndarray,
        tt: np.ndarray,
        seq: np.ndarray,
    ) -> np.ndarray:
        """All open samples (old and new, in n order) with the accepted frames merged in.

        A new sample takes its board time from its first accepted frame, every touched
        sample its receive time and seq from its last one. Grouped by a stable sort of
        the old rows then the frames (no sort at all for an in-order stream)."""
        old = self._open
        if len(n) == 0:
            return _rows_to_array(old)
        k = len(old)
        if k:
            cols = list(zip(*old, strict=True))
            all_n = np.concatenate((np.array(cols[0], dtype=np.int64), n))
        else:
            all_n = n
        perm = None
        if not bool(np.all(all_n[1:] >= all_n[:-1])):
            perm = np.argsort(all_n, kind="stable")
            all_n = all_n[perm]
        first = np.empty(len(all_n), dtype=bool)  # first of its sample (in sorted order)
        first[0] = True
        np.not_equal(all_n[1:], all_n[:-1], out=first[1:])
        last = np.empty_like(first)
        last[:-1] = first[1:]
        last[-1] = True
        gid = np.cumsum(first) - 1  # sample (table row) of each element, sorted order
        first_at, last_at = np.flatnonzero(first), np.flatnonzero(last)
        if perm is not None:
            first_at, last_at = perm[first_at], perm[last_at]
            gid_orig = np.empty_like(gid)
            gid_orig[perm] = gid
            gid = gid_orig
        rows = len(first_at)
        table = np.empty(rows, dtype=SAMPLE_DTYPE)  # every field is written below
        table["n"] = all_n[first]
        if k:
            big_t = np.concatenate((np.array(cols[1], dtype=np.int64), big_t))
            tt = np.concatenate((np.array(cols[2], dtype=np.float64), tt))
            seq = np.concatenate((np.array(cols[3], dtype=np.int64), seq))
        table["ticks"] = big_t[first_at]
        table["t"] = tt[last_at]
        table["seq"] = seq[last_at]
        # channels via flat (rows * 3) scratch arrays: contiguous scatters, one copy each
        code3 = np.zeros(rows * 3, dtype=np.int32)
        status3 = np.zeros(rows * 3, dtype=np.uint8)
        present3 = np.zeros(rows * 3, dtype=bool)
        for j, r in enumerate(old):
            at = int(gid[j]) * 3
            code3[at : at + 3], status3[at : at + 3], present3[at : at + 3] = r[4], r[5], r[6]
        flat = gid[k:] * 3 + (ch - 1)
        code3[flat] = code
        status3[flat] = status
        present3[flat] = True
        table["code"] = code3.reshape(rows, 3)
        table["status"] = status3.reshape(rows, 3)
        table["present"] = present3.reshape(rows, 3)
        return table

    def _emit_table(self, table: np.ndarray) -> np.ndarray:
        """_emit_rows for a table: every sample but the last WINDOW is closed."""
        bound = self.max_n - WINDOW
        i = int(np.searchsorted(table["n"], bound, side="right"))
        tail = _array_to_rows(table[i:])
        done = self._emit_rows(tail)
        return table[: i + len(done)]

    def _gap_events(self, out: np.ndarray) -> np.ndarray:
        """GAP and SAMPLES_LOST events of emitted samples."""
        if len(out) == 0:
            return NO_EVENTS
        parts = []
        present = out["present"]
        if not present.all():
            missing_row, missing_ch = np.nonzero(~present)
            parts.append(
                make_events(
                    EventKind.GAP, out["t"][missing_row], missing_ch + 1, out["n"][missing_row]
                )
            )
        n = out["n"]
        prev = _shifted(n, n[0] - 1 if self._last_row_n is None else self._last_row_n)
        lost = n - prev - 1
        idx = np.flatnonzero(lost > 0)
        if len(idx):
            parts.append(
                make_events(EventKind.SAMPLES_LOST, out["t"][idx], 0, prev[idx] + 1, lost[idx])
            )
        self._last_row_n = int(n[-1])
        return concat_events(parts)
