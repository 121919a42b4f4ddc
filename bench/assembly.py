"""Sample assembly: group the three channel frames of one sampling instant.

One algorithm serves live runs (batches of a few frames) and replay (batches of a
million): it is vectorised over a batch and carries its state across batches, and the
outcome does not depend on how the stream is cut into batches (tests prove it).

The rules, all driven by frame contents and order (never by wall-clock time), so a live
run and the replay of its log decide alike:

* Unwrapping. Each valid ADC frame gets an unwrapped sample index ``n`` relative to the
  previous valid ADC frame from the board-timestamp step (its 6.5536 s wraps resolved by
  the receive-time step). Once a BOARD_STATUS frame has given the sample rate, board time
  alone places the frame and a counter that disagrees is reported (COUNTER_JUMP, per
  frame and channel), so one channel's bad counter cannot pull the others apart. Before
  that, the counter (mod 256) corrects the predicted step. Counter wrap 255 -> 0 never
  splits a sample and long gaps do not alias.
* Membership. A frame joins sample ``n`` unless it is *late* (some earlier frame already
  reached ``n + WINDOW``: the sample was closed) or a *duplicate* (its channel already
  joined ``n``). Late and duplicate frames are counted and ignored.
* Emission. A sample is emitted when closed (overdue: the stream reached ``n + WINDOW``)
  or, earlier, when all three channels are in and every earlier sample is out. Output is
  always in ``n`` order. A closed sample proceeds without its missing channels.
"""

from __future__ import annotations

import numpy as np

from bench.events import EVENT_DTYPE, EventKind, concat_events, make_events
from protocol.batch import DecodedBatch
from protocol.layout import COUNTER_WRAP, STATUS_FAULT_MASK, TICK_S, TS_WRAP, FrameKind, Outcome

WINDOW = 2
"""Samples a sample may wait for its missing channels ("about two sample periods")."""

SAMPLE_DTYPE = np.dtype(
    [
        ("n", "<i8"),  # unwrapped sample index (counter)
        ("ticks", "<i8"),  # unwrapped board time, 100 us ticks
        ("t", "<f8"),  # receive time of the sample's last accepted frame
        ("seq", "<i8"),  # arrival index (whole stream) of the sample's last accepted frame
        ("code", "<i4", (3,)),  # raw ADC codes ch1..ch3 (0 where absent)
        ("status", "u1", (3,)),  # status bytes ch1..ch3
        ("present", "?", (3,)),  # a frame of that channel joined the sample
    ]
)

_NONE = np.iinfo(np.int64).min // 4
_ADC, _STATUS, _OK = int(FrameKind.ADC), int(FrameKind.STATUS), int(Outcome.OK)
_ERRORS = (
    (int(Outcome.CRC_MISMATCH), EventKind.CRC_ERROR, "can_id"),
    (int(Outcome.WRONG_DLC), EventKind.WRONG_DLC, "dlc"),
    (int(Outcome.UNKNOWN_ID), EventKind.UNKNOWN_ID, "can_id"),
)
MAX_BRIDGE_TICKS = 3600 / TICK_S
"""Longest receive-time gap (1 h) trusted to count board-timestamp wraps across."""


_NO_EVENTS = np.zeros(0, dtype=EVENT_DTYPE)


def _isin(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.isin, without its fixed cost for the few keys of a live batch."""
    if len(a) <= 16:
        members = set(b.tolist())
        return np.array([x in members for x in a.tolist()], dtype=bool)
    return np.isin(a, b)


def _first_of_each(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique values, index of each one's first occurrence); O(N) when ``a`` is sorted,
    as it is for an in-order stream, else np.unique's sort."""
    if len(a) == 0:
        return a, np.zeros(0, dtype=np.intp)
    if len(a) < 2 or bool(np.all(a[1:] >= a[:-1])):
        first = np.flatnonzero(np.concatenate(([True], a[1:] != a[:-1])))
        return a[first], first
    return np.unique(a, return_index=True)


def _last_of_each(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique values, index of each one's last occurrence)."""
    if len(a) == 0:
        return a, np.zeros(0, dtype=np.intp)
    if len(a) < 2 or bool(np.all(a[1:] >= a[:-1])):
        last = np.flatnonzero(np.concatenate((a[1:] != a[:-1], [True])))
        return a[last], last
    u, rev = np.unique(a[::-1], return_index=True)
    return u, len(a) - 1 - rev


def usable(samples: np.ndarray) -> np.ndarray:
    """(N, 3) bool: channel present and none of status bits 0..3 set."""
    return samples["present"] & ((samples["status"] & STATUS_FAULT_MASK) == 0)


class Assembler:
    """Stateful, vectorised sample assembly (see module docstring for the rules)."""

    def __init__(self, sample_rate_hz: float) -> None:
        self.period_ticks = 1.0 / (sample_rate_hz * TICK_S)
        self.rate_known = False  # set once a BOARD_STATUS frame has told us the rate
        self._chain: tuple[float, int, int, int, int] | None = (
            None  # t, ts, T, c, n of last ADC frame
        )
        self.max_n = _NONE
        self.last_emitted: int | None = None
        self._last_row_n: int | None = None
        self._open = np.zeros(0, dtype=SAMPLE_DTYPE)
        self._recent = np.zeros(0, dtype=SAMPLE_DTYPE)  # emitted complete, still within the window

    # -- helpers -------------------------------------------------------------------------
    def _periods(self, dec: DecodedBatch, adc_idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Period (ticks) in force at each ADC frame, and whether a status frame set it."""
        st = np.flatnonzero((dec.kind == _STATUS) & (dec.outcome == _OK) & (dec.sample_rate > 0))
        period = np.full(len(adc_idx), self.period_ticks)
        known = np.full(len(adc_idx), self.rate_known)
        if len(st):
            rates = dec.sample_rate[st].astype(np.float64)
            j = np.searchsorted(st, adc_idx) - 1
            has = j >= 0
            period[has] = 1.0 / (rates[j[has]] * TICK_S)
            known[has] = True
            self.period_ticks = 1.0 / (rates[-1] * TICK_S)
            self.rate_known = True
        return period, known

    def _accepted_keys(self) -> np.ndarray:
        rows = np.concatenate([self._open, self._recent]) if len(self._recent) else self._open
        nn, ch = np.nonzero(rows["present"])
        return rows["n"][nn] * 4 + ch + 1

    # -- main entry ----------------------------------------------------------------------
    def push(
        self, t: np.ndarray, dec: DecodedBatch, seq0: int = 0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Feed frames (receive times + decoded batch; ``seq0`` = arrival index of the first).

        Returns (emitted samples, events)."""
        events = [self._error_events(t, dec)]
        adc = np.flatnonzero((dec.kind == _ADC) & (dec.outcome == _OK))
        period, known = self._periods(dec, adc)
        if len(adc) == 0:
            return np.zeros(0, dtype=SAMPLE_DTYPE), concat_events(events)

        c = dec.counter[adc].astype(np.int64)
        ts = dec.timestamp[adc].astype(np.int64)
        tt = t[adc].astype(np.float64)
        ch = dec.channel[adc].astype(np.int64)
        if self._chain is None:
            self._chain = (float(tt[0]), int(ts[0]), int(ts[0]), int(c[0]), int(c[0]))
        t0, ts0, big_t0, c0, n0 = self._chain
        prev_t = np.concatenate(([t0], tt[:-1]))
        prev_ts = np.concatenate(([ts0], ts[:-1]))
        prev_c = np.concatenate(([c0], c[:-1]))

        d = (ts - prev_ts) % TS_WRAP
        d = np.where(d >= TS_WRAP // 2, d - TS_WRAP, d)
        with np.errstate(invalid="ignore", over="ignore"):
            dt_ticks = (tt - prev_t) / TICK_S
            # receive time bridges timestamp wraps only over plausible gaps: a corrupt or
            # missing receive time (0, 1e15, NaN) must not throw the sample index away
            plausible = np.isfinite(dt_ticks) & (np.abs(dt_ticks) <= MAX_BRIDGE_TICKS)
            wraps = np.where(plausible, np.rint((dt_ticks - d) / TS_WRAP), 0.0)
        d = d + TS_WRAP * np.maximum(wraps, 0.0).astype(np.int64)
        est = np.rint(d / period).astype(np.int64)
        dc = (c - prev_c - est + COUNTER_WRAP // 2) % COUNTER_WRAP - COUNTER_WRAP // 2
        # once the rate is known, board time places the frame and the counter is checked
        # against it; before that the counter leads and board time only bridges long gaps
        n = n0 + np.cumsum(np.where(known, est, est + dc))
        big_t = big_t0 + np.cumsum(d)
        self._chain = (float(tt[-1]), int(ts[-1]), int(big_t[-1]), int(c[-1]), int(n[-1]))

        mismatch = (c - n + COUNTER_WRAP // 2) % COUNTER_WRAP - COUNTER_WRAP // 2
        jump = (mismatch != 0) & known
        if jump.any():
            events.append(
                make_events(EventKind.COUNTER_JUMP, tt[jump], ch[jump], n[jump], mismatch[jump])
            )

        # membership: late, duplicate, accepted
        running = np.maximum.accumulate(np.maximum(n, self.max_n))
        max_before = np.concatenate(([self.max_n], running[:-1]))
        late = max_before >= n + WINDOW
        key = n * 4 + ch
        known = self._accepted_keys()
        fresh = np.flatnonzero(~late & ~_isin(key, known)) if len(known) else np.flatnonzero(~late)
        _, first = _first_of_each(key[fresh])
        acc = np.zeros(len(n), dtype=bool)
        acc[fresh[first]] = True
        dup = ~late & ~acc
        if late.any():
            events.append(make_events(EventKind.LATE, tt[late], ch[late], n[late]))
        if dup.any():
            events.append(make_events(EventKind.DUPLICATE, tt[dup], ch[dup], n[dup]))
        status = dec.status[adc]
        flagged = acc & ((status & STATUS_FAULT_MASK) != 0)
        if flagged.any():
            events.append(
                make_events(
                    EventKind.STATUS_FLAG, tt[flagged], ch[flagged], n[flagged], status[flagged]
                )
            )

        self._merge(
            n[acc], ch[acc], dec.code[adc][acc], status[acc], big_t[acc], tt[acc], seq0 + adc[acc]
        )
        self.max_n = int(running[-1])
        out = self._emit()
        events.append(self._gap_events(out))
        return out, concat_events(events)

    def finish(self) -> tuple[np.ndarray, np.ndarray]:
        """End of stream: emit every open sample as it is."""
        out = self._open
        self._open = np.zeros(0, dtype=SAMPLE_DTYPE)
        if len(out):
            self.last_emitted = int(out["n"][-1])
        return out, self._gap_events(out)

    # -- internals -----------------------------------------------------------------------
    def _error_events(self, t: np.ndarray, dec: DecodedBatch) -> np.ndarray:
        if not dec.outcome.any():
            return _NO_EVENTS
        parts = []
        for outcome, kind, field in _ERRORS:
            idx = np.flatnonzero(dec.outcome == outcome)
            if len(idx):
                value = getattr(dec, field)
                parts.append(make_events(kind, t[idx], dec.channel[idx], -1, value[idx]))
        return concat_events(parts)

    def _merge(self, n, ch, code, status, big_t, tt, seq) -> None:
        if len(n) == 0:
            return
        uniq, _ = _first_of_each(np.concatenate((self._open["n"], n)))
        table = np.zeros(len(uniq), dtype=SAMPLE_DTYPE)
        table["n"] = uniq
        table[np.searchsorted(uniq, self._open["n"])] = self._open
        pos = np.searchsorted(uniq, n)
        is_new = np.ones(len(uniq), dtype=bool)
        is_new[np.searchsorted(uniq, self._open["n"])] = False
        first_pos, first_idx = _first_of_each(pos)
        newrow = is_new[first_pos]
        table["ticks"][first_pos[newrow]] = big_t[first_idx[newrow]]
        last_pos, last_idx = _last_of_each(pos)
        table["t"][last_pos] = tt[last_idx]
        table["seq"][last_pos] = seq[last_idx]
        col = ch - 1
        table["code"][pos, col] = code
        table["status"][pos, col] = status
        table["present"][pos, col] = True
        self._open = table

    def _emit(self) -> np.ndarray:
        bound = self.max_n - WINDOW
        closed = self._open["n"] <= bound
        out = [self._open[closed]]
        rest = self._open[~closed]
        last = bound if self.last_emitted is None else max(self.last_emitted, bound)
        k = 0
        while k < len(rest) and rest["n"][k] == last + 1 and rest["present"][k].all():
            last += 1
            k += 1
        early = rest[:k]
        self._open = rest[k:]
        self.last_emitted = last
        if k:
            self._recent = np.concatenate([self._recent, early]) if len(self._recent) else early
        if len(self._recent):
            self._recent = self._recent[self._recent["n"] > bound]
        if not k:
            return out[0]
        return np.concatenate([out[0], early]) if len(out[0]) else early

    def _gap_events(self, out: np.ndarray) -> np.ndarray:
        if len(out) == 0:
            return np.zeros(0, dtype=EVENT_DTYPE)
        parts = []
        missing_row, missing_ch = np.nonzero(~out["present"])
        if len(missing_row):
            parts.append(
                make_events(
                    EventKind.GAP, out["t"][missing_row], missing_ch + 1, out["n"][missing_row]
                )
            )
        n = out["n"]
        prev = np.concatenate(
            ([n[0] - 1 if self._last_row_n is None else self._last_row_n], n[:-1])
        )
        lost = n - prev - 1
        idx = np.flatnonzero(lost > 0)
        if len(idx):
            parts.append(
                make_events(EventKind.SAMPLES_LOST, out["t"][idx], 0, prev[idx] + 1, lost[idx])
            )
        self._last_row_n = int(n[-1])
        return concat_events(parts)
