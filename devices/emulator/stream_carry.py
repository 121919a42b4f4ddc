"""What the virtual board's run carries from one block to the next, for the faults whose
effect crosses a block's end: a spike fault's pulses (:class:`Spikes`, driven by
:mod:`devices.emulator.engine`) and a reorder fault's delayed frames (:class:`Reorder`,
driven by :mod:`devices.emulator.stream`)."""

from __future__ import annotations

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.scenario import Fault

ROW_DTYPE = np.dtype(
    [
        ("can_id", "<u4"),
        ("data", "u1", (8,)),
        ("kind", "u1"),
        ("channel", "u1"),
        ("when_us", "<i8"),
        ("uid", "<i8"),  # its row of the chunk's nominal frames
        ("tag", "<i8"),  # the duplicate fault that made it a copy, 0 for an original
        ("rid", "<i8"),  # its place in the chunk's bus schedule
    ]
)
"""A frame of the chunked stream before its send time is set, with what faults select by
and where it came from."""


class Spikes:
    """One channel's spikes of a spike fault: positions as bits over the window, signs drawn
    in position order as the chunks reach them (those reaching into the next chunk kept)."""

    def __init__(
        self, channel: int, i0: int, length: int, bits: np.ndarray, signs: np.random.Generator
    ) -> None:
        self.channel, self.i0, self.length, self.bits, self.signs = channel, i0, length, bits, signs
        self.drawn = 0  # window offsets below this have their signs drawn
        self.kept = np.zeros(0, dtype=np.int64)  # starts (window offsets) still reaching on
        self.kept_sign = np.zeros(0, dtype=np.float64)

    def _starts(self, lo: int, hi: int) -> np.ndarray:
        """Window offsets in [lo, hi) where a spike starts."""
        lo, hi = max(lo, 0), min(hi, self.length)
        if lo >= hi:
            return np.zeros(0, dtype=np.int64)
        b0 = lo // 8
        raw = np.unpackbits(self.bits[b0 : (hi + 7) // 8])[lo - 8 * b0 : hi - 8 * b0]
        return np.flatnonzero(raw) + lo

    def pulses(self, a: int, m: int, width: int, amp: float) -> tuple[np.ndarray, np.ndarray]:
        """Local sample indices and values to add for chunk [a, a + m), ordered by offset k
        within the pulse, then by start (overlapping pulses add in the same order whatever
        the chunk)."""
        hi = a + m - self.i0
        new = self._starts(self.drawn, hi)
        self.drawn = max(self.drawn, min(hi, self.length))
        sign = np.where(self.signs.random(len(new)) < 0.5, -1.0, 1.0)
        starts = np.concatenate([self.kept, new])
        signs = np.concatenate([self.kept_sign, sign])
        live = starts + width - 1 >= a - self.i0  # still reaching into this chunk
        starts, signs = starts[live], signs[live]
        reach = starts + width - 1 >= hi  # reaching into the next chunk too
        self.kept, self.kept_sign = starts[reach], signs[reach]
        at = (starts[None, :] + np.arange(width, dtype=np.int64)[:, None]).ravel()
        value = np.tile(signs * amp, width)
        keep = (at < self.length) & (at >= a - self.i0) & (at < hi)
        return at[keep] + self.i0 - a, value[keep]


class Reorder:
    """One reorder fault over the frame stream: each picked frame goes ``depth`` places
    later (the others keep their order), send times stay with the places. Frames whose new
    place lies past what has arrived wait for the next chunk."""

    def __init__(self, fault: Fault, rng: np.random.Generator, keep: bool = False) -> None:
        self.fault, self.rng = fault, rng
        self.picked: list[np.ndarray] | None = [] if keep else None  # rids moved (keep)
        self.depth = fault.params["depth"]
        self.seen = 0  # frames that came in
        self.rows = np.zeros(0, dtype=ROW_DTYPE)  # waiting, with their sort keys
        self.keys = np.zeros(0, dtype=np.float64)
        self.slots = np.zeros(0, dtype=np.int64)  # send times of places not yet filled
        self.moved = 0

    def feed(
        self, rows: np.ndarray, send_us: np.ndarray, last: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        f = self.fault
        kind, ch, when = rows["kind"], rows["channel"], rows["when_us"]
        cand = fx.frame_targets(f, kind, ch) & fx.in_window(when, f)
        sel = fx.pick(cand, f.params["probability"], self.rng)
        self.moved += int(np.count_nonzero(sel))
        if self.picked is not None:
            self.picked.append(rows["rid"][sel])
        keys = np.arange(self.seen, self.seen + len(rows), dtype=np.float64)
        keys[sel] += self.depth + 0.5
        self.seen += len(rows)
        all_rows = np.concatenate([self.rows, rows])
        all_keys = np.concatenate([self.keys, keys])
        self.slots = np.concatenate([self.slots, send_us])
        order = np.argsort(all_keys, kind="stable")
        all_rows, all_keys = all_rows[order], all_keys[order]
        ready = len(all_keys) if last else int(np.searchsorted(all_keys, self.seen))
        out_rows, self.rows, self.keys = all_rows[:ready], all_rows[ready:], all_keys[ready:]
        out_t, self.slots = self.slots[:ready], self.slots[ready:]
        return out_rows, out_t

    def take_moved(self) -> int:
        moved, self.moved = self.moved, 0
        return moved
