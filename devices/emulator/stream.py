"""The virtual board's run in time chunks: what :func:`simulate` computes, a chunk of
sampling instants at a time, so a file of any length is written in bounded memory.

The chunks hold, concatenated, exactly the frames, truth and UART bytes of
``simulate(scenario)`` (tests/test_emulator_stream.py holds them equal bit for bit over the
fault kinds, with chunks small enough to split every fault window). That rests on:

* the samples come from the one world-to-sensor engine (:mod:`devices.emulator.engine`),
  which :func:`simulate` runs as a single block and this module block by block; it carries
  what crosses a block's end (generators, spike pulses, a stuck code);
* each random draw of the frame faults comes from its own generator (per layer and fault),
  drawn in frame order, and numpy's generators give the same numbers drawn in pieces as in
  one call;
* where :func:`simulate` draws twice from one fault's generator (a CRC fault picks its
  frames, then the bits it flips; a UART fault picks packets, then corrupts them), the
  second draw here comes from a copy advanced past the first draw's total, which a first,
  cheap pass (no sensor values, no payloads) counts;
* the bus schedule (each frame waits for the previous one) carries its last send time;
  a reorder fault carries the frames it delayed past the chunk's end into the next chunk.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.board import FrameSet, merge
from devices.emulator.engine import Engine, sample_us
from devices.emulator.scenario import Fault, Scenario
from devices.emulator.simulation import (
    FaultEffect,
    _speed_stream,
    _status_stream,
    _targeted,
    summary_headline,
)
from devices.emulator.stream_carry import ROW_DTYPE, Reorder
from protocol.frames import FRAME_DTYPE
from protocol.layout import FRAME_DLC, FrameKind

CHUNK_S = 10.0
"""Seconds of sampling instants per chunk (30 000 frames at 1 kHz: a few MB)."""

_HIT = ("drift", "spike", "saturate", "stuck", "status")


@dataclass(slots=True)
class Chunk:
    """One piece of the run: its frames (CAN order), the truth of its sampling instants and,
    when asked for, its part of the UART byte stream."""

    frames: np.ndarray
    truth: np.ndarray
    uart: bytes = b""


@dataclass
class RunCounts:
    """What :meth:`devices.emulator.simulation.Simulation.summary` says, counted as the
    chunks go by: frames per kind and, per fault, frames changed/added/moved and removed."""

    scenario: Scenario
    kinds: dict[int, int] = field(default_factory=dict)
    changed: dict[int, int] = field(default_factory=dict)  # fault index -> frames/packets
    removed: dict[int, int] = field(default_factory=dict)
    uart: bool = False  # the UART stream was generated
    frames: int = 0
    packets: int = 0
    uart_bytes: int = 0
    packets_broken: int = 0

    def add(self, index: int, changed: int = 0, removed: int = 0) -> None:
        self.changed[index] = self.changed.get(index, 0) + int(changed)
        self.removed[index] = self.removed.get(index, 0) + int(removed)

    def summary(self) -> str:
        sc = self.scenario
        lines = [summary_headline(sc, self.frames, self.kinds)]
        for f in sc.faults:
            if f.target == "uart":
                continue
            lines.append(f"  fault {self._effect(f).describe()}")
        for f in sc.faults:
            if f.target != "uart":
                continue
            if self.uart:
                lines.append(f"  fault {self._effect(f).describe()}")
            else:
                lines.append(f"  fault {f.label}: UART only (the UART stream was not generated)")
        return "\n".join(lines)

    def _effect(self, f: Fault) -> FaultEffect:
        """A FaultEffect of the right sizes, so the text is FaultEffect.describe()'s."""
        return FaultEffect(
            f,
            np.zeros(self.changed.get(f.index, 0), dtype=np.int64),
            np.zeros(self.removed.get(f.index, 0), dtype=np.int64),
        )


@dataclass
class _Totals:
    """How many numbers the first of two draws from one fault's generator takes, over the
    whole run (the second draw starts after them)."""

    crc: dict[int, int] = field(default_factory=dict)
    uart: dict[int, int] = field(default_factory=dict)


def simulate_chunks(
    sc: Scenario, *, uart: bool = False, chunk_s: float = CHUNK_S, counts: RunCounts | None = None
) -> Iterator[Chunk]:
    """The run of ``sc`` in chunks of ``chunk_s`` seconds of sampling instants: the frames,
    truth and (``uart``) UART bytes of ``simulate(sc)``, in order. ``counts`` (if given) is
    filled in as the chunks go, for the run's summary."""
    needs_totals = any(f.kind == "crc" for f in sc.faults) or (
        uart and any(f.target == "uart" for f in sc.faults)
    )
    totals = _Totals()
    if needs_totals:
        for _ in _Run(sc, uart, chunk_s, None, totals, None).chunks():
            pass
    yield from _Run(sc, uart, chunk_s, totals, None, counts).chunks()


class _Run:
    """One pass over the run. ``totals`` given: the real pass (it advances the second
    draws by them); ``count_into`` given: the counting pass (no values, no payloads)."""

    def __init__(
        self,
        sc: Scenario,
        uart: bool,
        chunk_s: float,
        totals: _Totals | None,
        count_into: _Totals | None,
        counts: RunCounts | None,
    ) -> None:
        self.sc, self.uart, self.counts = sc, uart, counts
        self.counting = count_into is not None
        self.count_into = count_into
        self.engine = Engine(sc, values=not self.counting)
        self.rate = sc.sample_rate_hz
        self.n = sc.n_samples
        self.step = max(1, round(chunk_s * self.rate))
        self.start_us = fx.to_us(sc.start_time_s)
        duration_us = fx.to_us(sc.duration_s)
        jumps = [f for f in sc.faults if f.kind == "counter_jump"]
        self.status_all = _status_stream(sc, duration_us, jumps)
        self.speed_all = _speed_stream(sc, duration_us, jumps)[0] if sc.speed_ref else None
        # one generator per (layer, fault), drawn in frame order across the chunks
        seed = sc.seed
        self.pick_rng = {f.index: fx.rng_for(seed, fx.LAYER_FAULT, f.index) for f in sc.faults}
        self.flip_rng: dict[int, np.random.Generator] = {}
        self.uart_pick: dict[int, np.random.Generator] = {}
        self.uart_rows: dict[int, np.random.Generator] = {}
        for f in sc.faults:
            if f.kind == "crc":
                g = fx.rng_for(seed, fx.LAYER_FAULT, f.index)
                g.bit_generator.advance((totals.crc if totals else {}).get(f.index, 0))
                self.flip_rng[f.index] = g
            if f.target == "uart":
                self.uart_pick[f.index] = fx.rng_for(seed, fx.LAYER_UART, f.index)
                g = fx.rng_for(seed, fx.LAYER_UART, f.index)
                g.bit_generator.advance((totals.uart if totals else {}).get(f.index, 0))
                self.uart_rows[f.index] = g
        self.last_send: int | None = None
        self.reorders = [
            Reorder(f, self.pick_rng[f.index]) for f in sc.faults if f.kind == "reorder"
        ]

    # -- the chunks ----------------------------------------------------------------------
    def chunks(self) -> Iterator[Chunk]:
        bounds = list(range(0, self.n, self.step)) or [0]
        latency = self.sc.board.latency_us
        for k, a in enumerate(bounds):
            b = min(self.n, a + self.step)
            last = k == len(bounds) - 1
            lo = None if k == 0 else int(sample_us(self.rate, np.array([a]))[0]) + latency
            hi = None if last else int(sample_us(self.rate, np.array([b]))[0]) + latency
            yield self._chunk(a, b, lo, hi, last)

    def _chunk(self, a: int, b: int, lo: int | None, hi: int | None, last: bool) -> Chunk:
        block = self.engine.block(a, b)
        parts = [block.adc, _between(self.status_all, lo, hi)]
        if self.speed_all is not None:
            parts.append(_between(self.speed_all, lo, hi))
        nominal = merge(parts)
        frames, packets = self._frames(nominal, block.hit, a, b - a, last)
        return Chunk(frames, block.truth, packets)

    def _frames(
        self, nominal: FrameSet, hit: dict[int, np.ndarray], a: int, m: int, last: bool
    ) -> tuple[np.ndarray, bytes]:
        """Source faults, the bus schedule and the adapter's faults on this chunk's nominal
        frames (simulate()'s layers 2 and 3)."""
        sc, counts = self.sc, self.counts
        n_nom = len(nominal)
        alive = np.ones(n_nom, dtype=bool)
        data = nominal.data if self.counting else nominal.data.copy()
        corrupted = np.zeros(n_nom, dtype=bool)
        crc_rows: dict[int, np.ndarray] = {}
        for f in sc.faults:
            if f.kind == "dropout":
                sel = _targeted(nominal, f) & alive
                alive &= ~sel
                if counts is not None:
                    counts.add(f.index, removed=np.count_nonzero(sel))
        for f in sc.faults:
            if f.kind == "crc":
                cand = _targeted(nominal, f) & alive & ~corrupted
                p = f.params["probability"]
                if self.count_into is not None and p < 1.0:
                    self.count_into.crc[f.index] = self.count_into.crc.get(f.index, 0) + int(
                        np.count_nonzero(cand)
                    )
                sel = fx.pick(cand, p, self.pick_rng[f.index])
                rows = np.flatnonzero(sel)
                if not self.counting:
                    fx.flip_bits(data, rows, self.flip_rng[f.index])
                corrupted |= sel
                crc_rows[f.index] = sel
        uids = np.flatnonzero(alive)
        tag = np.zeros(len(uids), dtype=np.int64)
        for f in sc.faults:
            if f.kind == "duplicate":
                cand = _targeted(nominal, f, uids) & (tag == 0)
                order, is_copy = fx.duplicate_rows(
                    len(uids), fx.pick(cand, f.params["probability"], self.pick_rng[f.index])
                )
                uids, tag = uids[order], np.where(is_copy, f.index, tag[order])
        queue = nominal.queue_us[uids]
        if self.last_send is not None and len(queue):
            queue = queue.copy()
            queue[0] = max(int(queue[0]), self.last_send + sc.board.frame_gap_us)
        send_us = fx.serialise(queue, sc.board.frame_gap_us)
        if len(send_us):
            self.last_send = int(send_us[-1])
        packets = b""
        if self.uart:
            on_uart = (tag == 0) & (nominal.kind[uids] != FrameKind.SPEED)
            packets = self._uart(nominal, data, uids[on_uart], send_us[on_uart])
        for f in sc.faults:
            if f.kind == "loss":
                sel = fx.pick(
                    _targeted(nominal, f, uids), f.params["probability"], self.pick_rng[f.index]
                )
                keep = ~sel
                uids, tag, send_us = uids[keep], tag[keep], send_us[keep]
                if counts is not None:
                    counts.add(f.index, removed=np.count_nonzero(sel))
        if counts is not None:
            self._count(nominal, hit, crc_rows, uids, tag, a, m)
        rows = np.zeros(len(uids), dtype=ROW_DTYPE)
        rows["can_id"] = nominal.can_id[uids]
        rows["data"] = data[uids]
        rows["kind"] = nominal.kind[uids]
        rows["channel"] = nominal.channel[uids]
        rows["when_us"] = nominal.when_us[uids]
        for stage in self.reorders:
            rows, send_us = stage.feed(rows, send_us, last)
            if counts is not None:
                counts.add(stage.fault.index, changed=stage.take_moved())
        frames = np.zeros(len(rows), dtype=FRAME_DTYPE)
        frames["t"] = (self.start_us + send_us) / 1e6
        frames["id"] = rows["can_id"]
        frames["dlc"] = FRAME_DLC
        frames["data"] = rows["data"]
        if counts is not None:
            counts.frames += len(frames)
            kinds, n = np.unique(rows["kind"], return_counts=True)
            for kind, c in zip(kinds.tolist(), n.tolist(), strict=True):
                counts.kinds[kind] = counts.kinds.get(kind, 0) + c
        return frames, packets

    def _count(
        self,
        nominal: FrameSet,
        hit: dict[int, np.ndarray],
        crc_rows: dict[int, np.ndarray],
        uids: np.ndarray,
        tag: np.ndarray,
        a: int,
        m: int,
    ) -> None:
        """The summary's figures of this chunk, as simulate()'s FaultEffects count them
        (frames after the adapter's losses; a reorder moves, it does not change)."""
        counts = self.counts
        assert counts is not None
        is_adc = nominal.kind == FrameKind.ADC
        local = np.where(is_adc, nominal.seq - a, 0)
        for f in self.sc.faults:
            if f.target == "uart":
                continue
            if f.kind in _HIT:
                mask = hit.get(f.index, np.zeros(m, dtype=bool))
                sel = is_adc & np.isin(nominal.channel, fx.target_channels(f)) & mask[local]
                counts.add(f.index, changed=np.count_nonzero(sel[uids]))
            elif f.kind == "crc":
                counts.add(f.index, changed=np.count_nonzero(crc_rows[f.index][uids]))
            elif f.kind == "counter_jump":
                counts.add(f.index, changed=np.count_nonzero(_targeted(nominal, f)[uids]))
            elif f.kind == "duplicate":
                counts.add(f.index, changed=np.count_nonzero(tag == f.index))

    def _uart(
        self, nominal: FrameSet, data: np.ndarray, board_uid: np.ndarray, send_us: np.ndarray
    ) -> bytes:
        """This chunk's UART packets with the UART faults (simulate()'s _uart_stream)."""
        from protocol.uart import encode_packet

        counts = self.counts
        bodies: list[bytes] = []
        if not self.counting:
            ids = nominal.can_id[board_uid].tolist()
            payload = data[board_uid].tobytes()
            bodies = [encode_packet(c, payload[8 * k : 8 * k + 8])[:-1] for k, c in enumerate(ids)]
        broken: set[int] = set()
        for f in self.sc.faults:
            if f.target != "uart":
                continue
            cand = fx.in_window(send_us, f)
            p = f.params["probability"]
            if self.count_into is not None and p < 1.0:
                self.count_into.uart[f.index] = self.count_into.uart.get(f.index, 0) + int(
                    np.count_nonzero(cand)
                )
            rows = np.flatnonzero(fx.pick(cand, p, self.uart_pick[f.index]))
            if self.counting:
                continue
            rng = self.uart_rows[f.index]
            for r in rows.tolist():
                if f.kind == "noise":
                    bodies[r] = fx.inject_noise(bodies[r], f.params["burst_bytes"], rng)
                else:
                    bodies[r] = fx.truncate(bodies[r], rng)
            broken.update(rows.tolist())
            if counts is not None:
                counts.add(f.index, changed=len(rows))
        out = b"".join(body + b"\x00" for body in bodies)
        if counts is not None:
            counts.uart = True
            counts.packets += len(board_uid)
            counts.uart_bytes += len(out)
            counts.packets_broken += len(broken)
        return out


def _between(fs: FrameSet, lo: int | None, hi: int | None) -> FrameSet:
    """The frames of a stream queued in [lo, hi) (None: open)."""
    i = 0 if lo is None else int(np.searchsorted(fs.queue_us, lo, side="left"))
    j = len(fs) if hi is None else int(np.searchsorted(fs.queue_us, hi, side="left"))
    return fs.take(np.arange(i, j))


__all__ = ["CHUNK_S", "Chunk", "RunCounts", "simulate_chunks"]
