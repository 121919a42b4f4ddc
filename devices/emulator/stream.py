"""The virtual board's run: the engine's samples -> nominal frames -> frame faults -> bus
schedule (-> UART packets), a chunk of sampling instants at a time, so a file of any length
is written in bounded memory; :func:`devices.emulator.simulation.simulate` is the same run
in one chunk, keeping what each fault did.

The chunks concatenated hold the one-chunk run's frames, truth and UART bytes bit for bit
(tests/test_emulator_stream.py cuts through every fault window), because:

* the engine (:mod:`devices.emulator.engine`) carries what crosses a block's end
  (generators, spike pulses, a stuck code);
* each fault draws from its own generator (per layer and fault) in frame order, and
  numpy's generators give the same numbers drawn in pieces as in one call;
* where one fault draws twice (a CRC fault picks frames, then the bits it flips; a UART
  fault picks packets, then corrupts them), the one-chunk run draws both from one
  generator and the chunked run the second from a copy advanced past the first draw's
  total, which a first, cheap pass (no sensor values, no payloads) counts;
* the bus schedule carries its last send time; a reorder fault carries the frames it
  delayed past the chunk's end into the next chunk.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.board import FrameSet, merge, speed_frames, status_frames
from devices.emulator.body_pitch import scenario_stations
from devices.emulator.engine import Block, Engine, sample_us
from devices.emulator.motion import scenario_motion
from devices.emulator.odometer import quantise_speed, wheel_error
from devices.emulator.scenario import Fault, Scenario
from devices.emulator.stream_carry import ROW_DTYPE, Reorder
from devices.emulator.thermal import Thermal
from protocol.frames import FRAME_DTYPE
from protocol.layout import (
    FRAME_DLC,
    SPEED_REF_RATE_HZ,
    STATUS_RATE_HZ,
    BoardState,
    FrameKind,
)

ODOMETER_TRUTH_DTYPE = np.dtype(
    [
        ("time_s", "<f8"),  # the instant the SPEED_REF frame is queued, frames' time base
        ("measured_s", "<f8"),  # the instant its speed describes (time_s - lag_s)
        ("train_speed_mps", "<f8"),  # the train's true speed then
        ("wheel_error_mps", "<f8"),  # wheel slide (< 0) or slip (> 0) then
        ("reported_mps", "<f8"),  # what the frame carries (noise, quantisation), m/s
        ("wheel_diameter_error", "<f8"),  # e: the wheel's speed is reported times (1 + e)
    ]
)
"""One row per SPEED_REF frame the odometer sends (delivered or not): what it got wrong."""

_EMPTY = np.zeros(0, dtype=np.int64)


@dataclass(frozen=True, slots=True, eq=False)
class FaultEffect:
    """What one scenario fault did to the output.

    ``frames``: indices into ``Simulation.frames`` (or, for UART faults, into the UART
    stream's packets) that the fault changed, added (duplicate copies) or moved (reorder).
    ``removed_uids``: identities (``Simulation.nominal`` rows) of frames it removed.
    ``samples``: ADC sample indices n it acted on.
    """

    fault: Fault
    frames: np.ndarray = field(default_factory=lambda: _EMPTY)
    removed_uids: np.ndarray = field(default_factory=lambda: _EMPTY)
    samples: np.ndarray = field(default_factory=lambda: _EMPTY)

    @property
    def count(self) -> int:
        return len(self.frames) + len(self.removed_uids)

    def describe(self) -> str:
        parts = []
        if len(self.frames):
            verb = {
                "duplicate": "added",
                "reorder": "moved",
                "noise": "broke",
                "truncation": "broke",
            }
            unit = "packets" if self.fault.target == "uart" else "frames"
            parts.append(f"{verb.get(self.fault.kind, 'changed')} {len(self.frames)} {unit}")
        if len(self.removed_uids):
            parts.append(f"removed {len(self.removed_uids)} frames")
        return f"{self.fault.label}: {', '.join(parts) or 'no effect'}"


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
    """A run's summary, counted as the chunks go by (or from a whole run's FaultEffects):
    frames per kind and, per fault, frames changed/added/moved and removed."""

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
        """What ran, how many frames of each kind and what each fault did, one per line."""
        sc, kinds = self.scenario, self.kinds
        lines = [
            f"{sc.source}: {sc.duration_s:g} s at {sc.sample_rate_hz} Hz, seed {sc.seed}: "
            f"{self.frames} frames ({kinds.get(FrameKind.ADC, 0)} ADC, "
            f"{kinds.get(FrameKind.STATUS, 0)} status, {kinds.get(FrameKind.SPEED, 0)} speed)"
        ]
        lines += [f"  fault {self._effect(f).describe()}" for f in sc.faults if f.target != "uart"]
        for f in sc.faults:
            if f.target == "uart":
                lines.append(
                    f"  fault {self._effect(f).describe()}"
                    if self.uart
                    else f"  fault {f.label}: UART only (the UART stream was not generated)"
                )
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


@dataclass
class Kept:
    """What the run of the whole scenario in one chunk keeps to say what each fault did
    (:func:`devices.emulator.simulation.simulate`): nominal rows each fault removed or
    corrupted, the board's frames as sent on the UART and the payloads they carry."""

    removed: dict[int, np.ndarray] = field(default_factory=dict)  # dropout: nominal rows
    crc: dict[int, np.ndarray] = field(default_factory=dict)  # nominal frames corrupted (mask)
    lost: dict[int, np.ndarray] = field(default_factory=dict)  # loss: nominal rows
    board_uid: np.ndarray = field(default_factory=lambda: _EMPTY)
    board_send_us: np.ndarray = field(default_factory=lambda: _EMPTY)
    data: np.ndarray = field(default_factory=lambda: np.zeros((0, 8), dtype=np.uint8))
    rows: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=ROW_DTYPE))


class _Run:
    """One pass over the run. ``totals`` given: the real pass (it advances the second
    draws by them); ``count_into`` given: the counting pass (no values, no payloads);
    ``kept`` given: the whole run as one chunk, whose second draws follow the first on
    the same generator."""

    def __init__(
        self,
        sc: Scenario,
        uart: bool,
        chunk_s: float,
        totals: _Totals | None,
        count_into: _Totals | None,
        counts: RunCounts | None,
        kept: Kept | None = None,
    ) -> None:
        self.sc, self.uart, self.counts, self.kept = sc, uart, counts, kept
        self.counting = count_into is not None
        self.count_into = count_into
        self.engine = Engine(sc, values=not self.counting)
        self.rate = sc.sample_rate_hz
        self.n = sc.n_samples
        self.step = max(1, self.n if kept else round(chunk_s * self.rate))
        self.start_us = fx.to_us(sc.start_time_s)
        duration_us = fx.to_us(sc.duration_s)
        jumps = [f for f in sc.faults if f.kind == "counter_jump"]
        self.status_all = _status_stream(sc, duration_us, jumps)
        self.speed_all: FrameSet | None = None
        self.odometer = np.zeros(0, dtype=ODOMETER_TRUTH_DTYPE)
        if sc.speed_ref:
            self.speed_all, self.odometer = _speed_stream(sc, duration_us, jumps)
        # one generator per (layer, fault), drawn in frame order across the chunks
        seed = sc.seed
        self.pick_rng = {f.index: fx.rng_for(seed, fx.LAYER_FAULT, f.index) for f in sc.faults}
        self.flip_rng: dict[int, np.random.Generator] = {}
        self.uart_pick: dict[int, np.random.Generator] = {}
        self.uart_rows: dict[int, np.random.Generator] = {}
        for f in sc.faults:
            if f.kind == "crc":
                g = self.pick_rng[f.index] if kept else fx.rng_for(seed, fx.LAYER_FAULT, f.index)
                g.bit_generator.advance((totals.crc if totals else {}).get(f.index, 0))
                self.flip_rng[f.index] = g
            if f.target == "uart":
                self.uart_pick[f.index] = fx.rng_for(seed, fx.LAYER_UART, f.index)
                g = fx.rng_for(seed, fx.LAYER_UART, f.index)
                g.bit_generator.advance((totals.uart if totals else {}).get(f.index, 0))
                self.uart_rows[f.index] = g
        self.last_send: int | None = None
        self.reorders = [
            Reorder(f, self.pick_rng[f.index], keep=kept is not None)
            for f in sc.faults
            if f.kind == "reorder"
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
            block, nominal = self.nominal(a, b, lo, hi)
            frames, packets = self._frames(nominal, block.hit, a, b - a, last)
            yield Chunk(frames, block.truth, packets)

    def nominal(self, a: int, b: int, lo: int | None, hi: int | None) -> tuple[Block, FrameSet]:
        """The engine's block of instants [a, b) and the nominal frames queued in [lo, hi)."""
        block = self.engine.block(a, b)
        parts = [block.adc, _between(self.status_all, lo, hi)]
        if self.speed_all is not None:
            parts.append(_between(self.speed_all, lo, hi))
        return block, merge(parts)

    def frames(self, nominal: FrameSet, hit: dict[int, np.ndarray], m: int) -> np.ndarray:
        """The whole run's frames from its nominal ones (``kept`` filled in)."""
        return self._frames(nominal, hit, 0, m, True)[0]

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
        kept = self.kept
        for f in sc.faults:
            if f.kind == "dropout":
                sel = _targeted(nominal, f) & alive
                alive &= ~sel
                if counts is not None:
                    counts.add(f.index, removed=np.count_nonzero(sel))
                if kept:
                    kept.removed[f.index] = np.flatnonzero(sel)
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
                if kept:
                    kept.crc[f.index] = sel
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
        on_uart = (tag == 0) & (nominal.kind[uids] != FrameKind.SPEED)
        if self.uart:
            packets = self._uart(nominal, data, uids[on_uart], send_us[on_uart])
        if kept:
            kept.board_uid, kept.board_send_us, kept.data = uids[on_uart], send_us[on_uart], data
        rid = np.arange(len(uids), dtype=np.int64)
        for f in sc.faults:
            if f.kind == "loss":
                sel = fx.pick(
                    _targeted(nominal, f, uids), f.params["probability"], self.pick_rng[f.index]
                )
                if kept:
                    kept.lost[f.index] = uids[sel]
                keep = ~sel
                uids, tag, rid, send_us = uids[keep], tag[keep], rid[keep], send_us[keep]
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
        rows["uid"], rows["tag"], rows["rid"] = uids, tag, rid
        for stage in self.reorders:
            rows, send_us = stage.feed(rows, send_us, last)
            if counts is not None:
                counts.add(stage.fault.index, changed=stage.take_moved())
        frames = np.zeros(len(rows), dtype=FRAME_DTYPE)
        frames["t"] = (self.start_us + send_us) / 1e6
        frames["id"] = rows["can_id"]
        frames["dlc"] = FRAME_DLC
        frames["data"] = rows["data"]
        if kept:
            kept.rows = rows
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
        """This chunk's UART packets with the UART faults."""
        if self.count_into is not None:
            for f in self.sc.faults:
                if f.target == "uart" and f.params["probability"] < 1.0:
                    cand = int(np.count_nonzero(fx.in_window(send_us, f)))
                    self.count_into.uart[f.index] = self.count_into.uart.get(f.index, 0) + cand
            return b""
        ids, payload, rngs = nominal.can_id[board_uid], data[board_uid], self.uart_pick
        bodies, broken = uart_packets(self.sc, ids, payload, send_us, rngs, self.uart_rows)
        out = b"".join(body + b"\x00" for body in bodies)
        if self.counts is not None:
            for index, rows in broken.items():
                self.counts.add(index, changed=len(rows))
            self.counts.uart = True
            self.counts.packets += len(board_uid)
            self.counts.uart_bytes += len(out)
            self.counts.packets_broken += len(np.unique(np.concatenate([_EMPTY, *broken.values()])))
        return out


def uart_packets(
    sc: Scenario,
    can_id: np.ndarray,
    data: np.ndarray,
    send_us: np.ndarray,
    pick: Mapping[int, np.random.Generator],
    corrupt: Mapping[int, np.random.Generator],
) -> tuple[list[bytes], dict[int, np.ndarray]]:
    """The board's frames as UART packets (each without its closing 0x00), with the UART
    faults: each picks packets by its ``pick`` generator, then breaks them by ``corrupt``
    (the same generator for a whole run). Also, per fault, the rows it broke."""
    from protocol.uart import encode_packet

    payload = data.tobytes()
    ids = can_id.tolist()
    bodies = [encode_packet(c, payload[8 * k : 8 * k + 8])[:-1] for k, c in enumerate(ids)]
    broken: dict[int, np.ndarray] = {}
    for f in sc.faults:
        if f.target != "uart":
            continue
        rows = np.flatnonzero(
            fx.pick(fx.in_window(send_us, f), f.params["probability"], pick[f.index])
        )
        rng = corrupt[f.index]
        for r in rows.tolist():
            if f.kind == "noise":
                bodies[r] = fx.inject_noise(bodies[r], f.params["burst_bytes"], rng)
            else:
                bodies[r] = fx.truncate(bodies[r], rng)
        broken[f.index] = rows
    return bodies, broken


def _jump_offsets(f_list: list[Fault], target: str, when_us: np.ndarray) -> np.ndarray:
    out = np.zeros(len(when_us), dtype=np.int64)
    for f in f_list:
        if f.target in (target, "bus"):
            out[fx.in_window(when_us, f)] += f.params["jump"]
    return out


def _status_stream(sc: Scenario, duration_us: int, jumps: list[Fault]) -> FrameSet:
    period = 1_000_000 // STATUS_RATE_HZ
    when = np.arange(sc.board.status_offset_us, duration_us, period, dtype=np.int64)
    k = np.arange(len(when), dtype=np.int64)
    degraded = np.zeros(len(when), dtype=bool)
    errors = np.full(len(when), sc.board.errors0, dtype=np.int64)
    for f in sc.faults:
        if f.kind == "status":
            degraded |= fx.in_window(when, f)
        if f.kind in ("status", "saturate"):  # the board notices these and counts them
            errors += when >= fx.to_us(f.start_s)
    states = np.where(degraded, BoardState.DEGRADED, BoardState.RUN)
    counters = sc.board.status_counter0 + k + _jump_offsets(jumps, "status", when)
    b = sc.board
    board_t = Thermal(sc, scenario_stations(sc)).board(when / 1e6)
    temps = np.clip(np.rint(board_t), -128, 127).astype(np.int64)
    return status_frames(
        sc.base_id, when, counters, states, sc.sample_rate_hz, temps, b.supply_v, errors
    )


def _speed_stream(
    sc: Scenario, duration_us: int, jumps: list[Fault]
) -> tuple[FrameSet, np.ndarray]:
    """SPEED_REF on the odometer's own clock: it sends every 20 ms of ITS time, so a clock
    drift changes the true spacing; its timestamps start at its own time0. Also the
    odometer's truth (ODOMETER_TRUTH_DTYPE) per frame."""
    od = sc.odometer
    period_s = 1.0 / SPEED_REF_RATE_HZ
    rate = 1.0 + od.drift_ppm * 1e-6
    m_count = max(int((sc.duration_s * rate - od.offset_s) / period_s) + 2, 0)
    m = np.arange(m_count, dtype=np.int64)
    when = np.rint((od.offset_s + m * period_s) / rate * 1e6).astype(np.int64)
    keep = when < duration_us
    m, when = m[keep], when[keep]
    measured = when / 1e6 - od.lag_s
    v = scenario_motion(sc, measured)
    wheel = wheel_error(
        od, measured, v.accel_mps2, v.speed_mps, sc.duration_s, fx.rng_for(sc.seed, fx.LAYER_WHEEL)
    )
    speed = v.speed_mps + wheel
    if od.wheel_diameter_error:  # a worn (or wrongly configured) wheel: every turn is
        speed = speed * (1.0 + od.wheel_diameter_error)  # taken for 1 + e of its length
    if od.noise_mps:
        noise = od.noise_mps * fx.rng_for(sc.seed, fx.LAYER_ODOMETER).standard_normal(len(m))
        # a wheel-pulse odometer at rest reads 0
        speed = np.where(v.speed_mps == 0.0, 0.0, speed + noise)
    mm = quantise_speed(speed, od.resolution_mps)
    ticks = od.time0_ticks + round(od.offset_s * 1e4) + m * (10_000 // SPEED_REF_RATE_HZ)
    counters = od.counter0 + m + _jump_offsets(jumps, "speed", when)
    truth = np.zeros(len(m), dtype=ODOMETER_TRUTH_DTYPE)
    start_us = fx.to_us(sc.start_time_s)
    truth["time_s"] = (start_us + when) / 1e6
    truth["measured_s"] = truth["time_s"] - od.lag_s
    truth["train_speed_mps"] = v.speed_mps
    truth["wheel_error_mps"] = wheel
    truth["reported_mps"] = mm / 1000.0
    truth["wheel_diameter_error"] = od.wheel_diameter_error
    return speed_frames(when, counters, mm, ticks), truth


def _targeted(nominal: FrameSet, f: Fault, rows: np.ndarray | None = None) -> np.ndarray:
    """Frames (all nominal ones, or the given rows) a frame fault aims at, inside its window."""
    kind, ch, when = nominal.kind, nominal.channel, nominal.when_us
    if rows is not None:
        kind, ch, when = kind[rows], ch[rows], when[rows]
    return fx.frame_targets(f, kind, ch) & fx.in_window(when, f)


def _between(fs: FrameSet, lo: int | None, hi: int | None) -> FrameSet:
    """The frames of a stream queued in [lo, hi) (None: open)."""
    i = 0 if lo is None else int(np.searchsorted(fs.queue_us, lo, side="left"))
    j = len(fs) if hi is None else int(np.searchsorted(fs.queue_us, hi, side="left"))
    return fs.take(np.arange(i, j))


__all__ = ["CHUNK_S", "Chunk", "RunCounts", "simulate_chunks"]
