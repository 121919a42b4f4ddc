"""The virtual board's run in time chunks: what :func:`simulate` computes, a chunk of
sampling instants at a time, so a file of any length is written in bounded memory.

The chunks hold, concatenated, exactly the frames, truth and UART bytes of
``simulate(scenario)`` (tests/test_emulator_stream.py holds them equal bit for bit over the
fault kinds, with chunks small enough to split every fault window). That rests on:

* the world, the sensors and the board are functions of the instant; each random draw
  comes from its own generator (per layer and fault), drawn in frame order, and numpy's
  generators give the same numbers drawn in pieces as in one call;
* where :func:`simulate` draws twice from one fault's generator (a CRC fault picks its
  frames, then the bits it flips; a UART fault picks packets, then corrupts them), the
  second draw here comes from a copy advanced past the first draw's total, which a first,
  cheap pass (no sensor values, no payloads) counts;
* the bus schedule (each frame waits for the previous one) carries its last send time;
  a reorder fault carries the frames it delayed past the chunk's end into the next chunk;
  a stuck fault carries the code it repeats; spike positions are drawn for the whole
  window up front (a few integers per spike).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.board import FrameSet, adc_frames, merge
from devices.emulator.motion import scenario_motion
from devices.emulator.scenario import Fault, Scenario
from devices.emulator.simulation import (
    TRUTH_DTYPE,
    FaultEffect,
    _speed_stream,
    _status_stream,
    _targeted,
)
from devices.emulator.stream_carry import ROW_DTYPE, Reorder, Spikes
from devices.emulator.vibration import body_vibration
from devices.emulator.world import (
    board_temperature,
    body_specific_force,
    curve_normal_accel,
    gradient_profile,
    gradient_slope,
    quantise,
    sensor_output,
    specific_force,
)
from protocol.frames import FRAME_DTYPE
from protocol.layout import FRAME_DLC, STATUS_OVR, FrameKind

CHUNK_S = 10.0
"""Seconds of sampling instants per chunk (30 000 frames at 1 kHz: a few MB)."""

_VALUE = ("drift", "spike", "saturate")
_HIT = (*_VALUE, "stuck", "status")


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
        k = self.kinds
        lines = [
            f"{sc.source}: {sc.duration_s:g} s at {sc.sample_rate_hz} Hz, seed {sc.seed}: "
            f"{self.frames} frames ({k.get(FrameKind.ADC, 0)} ADC, "
            f"{k.get(FrameKind.STATUS, 0)} status, {k.get(FrameKind.SPEED, 0)} speed)"
        ]
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
        self.rate = sc.sample_rate_hz
        self.n = sc.n_samples
        self.step = max(1, round(chunk_s * self.rate))
        self.start_us = fx.to_us(sc.start_time_s)
        duration_us = fx.to_us(sc.duration_s)
        self.jumps = [f for f in sc.faults if f.kind == "counter_jump"]
        self.status_all = _status_stream(sc, duration_us, self.jumps)
        self.speed_all = _speed_stream(sc, duration_us, self.jumps)[0] if sc.speed_ref else None
        # one generator per (layer, fault), drawn in frame order across the chunks
        seed = sc.seed
        self.noise = [fx.rng_for(seed, fx.LAYER_NOISE, i + 1) for i in range(len(sc.channels))]
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
        self.spikes = {} if self.counting else self._spike_plans()
        self.stuck_carry: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.last_send: int | None = None
        self.reorders = [
            Reorder(f, self.pick_rng[f.index]) for f in sc.faults if f.kind == "reorder"
        ]

    # -- whole-run plans -----------------------------------------------------------------
    def _sample_us(self, idx: np.ndarray) -> np.ndarray:
        return (idx * 1_000_000 + self.rate // 2) // self.rate

    def _spike_plans(self) -> dict[int, list[Spikes]]:
        """Per spike fault, per channel, the spike positions apply_value_fault draws for the
        whole window (as bits: 1/8 byte per sample); their signs are drawn as chunks need
        them (they come after the positions from the same generator, in position order)."""
        plans: dict[int, list[Spikes]] = {}
        for f in self.sc.faults:
            if f.kind != "spike":
                continue
            rng = self.pick_rng[f.index]
            i0 = self._first_sample_at(fx.to_us(f.start_s))
            length = max(0, self._first_sample_at(fx.to_us(f.end_s)) - i0)
            plans[f.index] = []
            for ch in fx.target_channels(f):
                if length == 0:
                    continue
                expected = f.params["rate_hz"] * length / self.rate
                size = min(rng.poisson(expected), length)
                bits = np.zeros(length, dtype=bool)
                for done in range(0, size, 1 << 20):  # rng.choice(idx, size), in pieces
                    bits[rng.integers(0, length, size=min(1 << 20, size - done))] = True
                count = int(np.count_nonzero(bits))
                signs = np.random.Generator(type(rng.bit_generator)())
                signs.bit_generator.state = rng.bit_generator.state
                for done in range(0, count, 1 << 20):  # past the signs: the next channel's
                    rng.random(min(1 << 20, count - done))  # (advance() would drop a
                    # buffered half-word of the position draws)
                plans[f.index].append(Spikes(ch, i0, length, np.packbits(bits), signs))
        return plans

    def _first_sample_at(self, us: int) -> int:
        """The first sample index whose instant is >= ``us`` (n if none)."""
        lo, hi = 0, self.n
        while lo < hi:
            mid = (lo + hi) // 2
            if int(self._sample_us(np.array([mid]))[0]) < us:
                lo = mid + 1
            else:
                hi = mid
        return lo

    # -- the chunks ----------------------------------------------------------------------
    def chunks(self) -> Iterator[Chunk]:
        bounds = list(range(0, self.n, self.step)) or [0]
        latency = self.sc.board.latency_us
        for k, a in enumerate(bounds):
            b = min(self.n, a + self.step)
            last = k == len(bounds) - 1
            lo = None if k == 0 else int(self._sample_us(np.array([a]))[0]) + latency
            hi = None if last else int(self._sample_us(np.array([b]))[0]) + latency
            yield self._chunk(a, b, lo, hi, last)

    def _chunk(self, a: int, b: int, lo: int | None, hi: int | None, last: bool) -> Chunk:
        sc = self.sc
        idx = np.arange(a, b, dtype=np.int64)
        sample_us = self._sample_us(idx)
        m = len(idx)
        hit: dict[int, np.ndarray] = {}  # fault index -> local sample mask
        if self.counting:
            codes = np.zeros((3, m), dtype=np.int64)
            status = np.zeros((3, m), dtype=np.uint8)
        else:
            codes, status = self._board(idx, sample_us, hit)
        counters = np.tile(sc.counter0 + idx, (3, 1))
        for f in self.jumps:
            win = fx.in_window(sample_us, f)
            for ch in fx.target_channels(f):
                counters[ch - 1, win] += f.params["jump"]
        ticks = sc.board_time0_ticks + (idx * 10_000 + self.rate // 2) // self.rate
        adc = adc_frames(sc.base_id, sample_us, sc.board.latency_us, counters, codes, status, ticks)
        adc.seq += a
        parts = [adc, _between(self.status_all, lo, hi)]
        if self.speed_all is not None:
            parts.append(_between(self.speed_all, lo, hi))
        nominal = merge(parts)
        frames, packets = self._frames(nominal, hit, a, m, last)
        truth = np.zeros(0, dtype=TRUTH_DTYPE) if self.counting else self._truth(idx, sample_us)
        return Chunk(frames, truth, packets)

    def _board(
        self, idx: np.ndarray, sample_us: np.ndarray, hit: dict[int, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sensor values -> codes and status of these instants, board faults applied."""
        sc = self.sc
        t = sample_us / 1e6
        motion = scenario_motion(sc, t)
        grad = gradient_profile(sc.track, sc.vertical_curve_m, motion.position_m)
        body_x, body_z = body_vibration(
            sc.vibration, t, motion.speed_mps, fx.rng_for(sc.seed, fx.LAYER_VIBRATION)
        )
        if sc.vertical_curve_accel:
            slope = gradient_slope(sc.track, sc.vertical_curve_m, motion.position_m)
            body_z += curve_normal_accel(motion.speed_mps, grad, slope)
        extra = sc.vibration.active or sc.vertical_curve_accel
        rise = board_temperature(sc.board, t) - sc.board.temperature_c
        m = len(idx)
        values = np.empty((3, m), dtype=np.float64)
        for i, ch in enumerate(sc.channels):
            if extra:
                ideal = body_specific_force(
                    motion.accel_mps2, grad, sc.g, ch.angle_deg, body_x, body_z
                )
            else:
                ideal = specific_force(motion.accel_mps2, grad, sc.g, ch.angle_deg)
            values[i] = sensor_output(ideal, ch, t, self.noise[i], rise)
        a = int(idx[0]) if m else 0
        for f in sc.faults:
            if f.kind in ("drift", "saturate"):
                rows = fx.apply_value_fault(values, f, sample_us, self.rate, self.pick_rng[f.index])
                hit[f.index] = _mask(rows, m)
            elif f.kind == "spike":
                mask = np.zeros(m, dtype=bool)
                width, amp = f.params["width_samples"], f.params["amplitude_mps2"]
                for plan in self.spikes[f.index]:
                    at, value = plan.pulses(a, m, width, amp)
                    np.add.at(values[plan.channel - 1], at, value)  # in order, as k by k
                    mask[at] = True
                hit[f.index] = mask
        codes, over = quantise(values)
        status = np.where(over, STATUS_OVR, 0).astype(np.uint8)
        for f in sc.faults:
            if f.kind == "stuck":
                hit[f.index] = self._stuck(f, codes, status, sample_us, a)
        for f in sc.faults:
            if f.kind == "status":
                hit[f.index] = _mask(fx.apply_status_bits(status, f, sample_us), m)
        return codes, status

    def _stuck(
        self, f: Fault, codes: np.ndarray, status: np.ndarray, sample_us: np.ndarray, a: int
    ) -> np.ndarray:
        """apply_stuck over chunks: the value repeated is the one at the sample before the
        window (or the first), taken in the chunk that holds it, before this fault acts."""
        m = len(sample_us)
        first = self._first_sample_at(fx.to_us(f.start_s))
        end = self._first_sample_at(fx.to_us(f.end_s))
        if first >= end:
            return np.zeros(m, dtype=bool)
        src = max(first - 1, 0)
        chans = [ch - 1 for ch in fx.target_channels(f)]
        if a <= src < a + m:
            self.stuck_carry[f.index] = (
                codes[chans, src - a].copy(),
                status[chans, src - a].copy(),
            )
        win = fx.in_window(sample_us, f)
        if not win.any():
            return win
        held_codes, held_status = self.stuck_carry[f.index]
        for j, ch in enumerate(chans):
            code = f.params["code"]
            codes[ch, win] = held_codes[j] if code is None else code
            status[ch, win] = held_status[j] if code is None else 0
        return win

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

    def _truth(self, idx: np.ndarray, sample_us: np.ndarray) -> np.ndarray:
        sc = self.sc
        motion = scenario_motion(sc, sample_us / 1e6)
        truth = np.zeros(len(idx), dtype=TRUTH_DTYPE)
        truth["time_s"] = (self.start_us + sample_us) / 1e6
        truth["counter"] = sc.counter0 + idx
        truth["gradient_permil"] = gradient_profile(
            sc.track, sc.vertical_curve_m, motion.position_m
        )
        truth["accel_mps2"] = motion.accel_mps2
        truth["speed_mps"] = motion.speed_mps
        truth["position_m"] = motion.position_m
        return truth


def _between(fs: FrameSet, lo: int | None, hi: int | None) -> FrameSet:
    """The frames of a stream queued in [lo, hi) (None: open)."""
    i = 0 if lo is None else int(np.searchsorted(fs.queue_us, lo, side="left"))
    j = len(fs) if hi is None else int(np.searchsorted(fs.queue_us, hi, side="left"))
    return fs.take(np.arange(i, j))


def _mask(rows: np.ndarray, m: int) -> np.ndarray:
    out = np.zeros(m, dtype=bool)
    out[rows] = True
    return out


__all__ = ["CHUNK_S", "Chunk", "RunCounts", "simulate_chunks"]
