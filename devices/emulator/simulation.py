"""simulate(scenario) -> Simulation: every frame the virtual board run sends, its truth and
what each fault did. Pure and deterministic: the same scenario (seed included) gives the
same frames bit for bit.

Send times are whole microseconds (``t = us / 1e6``) so that a candump text log, which
prints six decimals, parses back to the identical float64.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.board import FrameSet, merge, speed_frames, status_frames
from devices.emulator.body_pitch import scenario_stations
from devices.emulator.engine import Engine
from devices.emulator.motion import scenario_motion
from devices.emulator.odometer import quantise_speed, wheel_error
from devices.emulator.scenario import Fault, Scenario
from devices.emulator.thermal import Thermal
from devices.errors import BenchError
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


@dataclass(frozen=True, slots=True, eq=False)
class UartStream:
    """The board's UART byte stream (ICD section 2) with the UART faults applied."""

    data: bytes
    packet_t: np.ndarray  # float64 send time of each packet, s
    packet_end: np.ndarray  # int64 offset just past each packet's 0x00 in ``data``
    packet_uid: np.ndarray  # int64 nominal identity of the frame each packet carries
    broken: np.ndarray  # int64 indices of the packets a UART fault broke (sorted, unique)
    effects: tuple[FaultEffect, ...]

    @property
    def packets_broken(self) -> int:
        return len(self.broken)

    def __len__(self) -> int:
        return len(self.packet_t)


@dataclass(eq=False)
class Simulation:
    scenario: Scenario
    frames: np.ndarray  # FRAME_DTYPE, CAN send (and receive) order
    frame_uid: np.ndarray  # int64: row of ``nominal`` each frame came from (copies share it)
    frame_copy: np.ndarray  # bool: a duplicate-fault copy
    truth: np.ndarray  # TRUTH_DTYPE, one row per sampling instant
    effects: tuple[FaultEffect, ...]
    nominal: FrameSet  # the fault-free sequence in bus order (uid = row)
    board_uid: np.ndarray  # the board's frames as sent on the UART: identity...
    board_send_us: np.ndarray  # ...and send time (relative us)
    board_data: np.ndarray  # (N, 8) payloads as sent (source faults applied)
    odometer: np.ndarray = field(  # ODOMETER_TRUTH_DTYPE, one row per SPEED_REF sent
        default_factory=lambda: np.zeros(0, dtype=ODOMETER_TRUTH_DTYPE)
    )
    _uart: UartStream | None = None

    # per-frame facts, by identity
    @property
    def frame_kind(self) -> np.ndarray:
        return self.nominal.kind[self.frame_uid]

    @property
    def frame_channel(self) -> np.ndarray:
        return self.nominal.channel[self.frame_uid]

    @property
    def frame_seq(self) -> np.ndarray:
        """Sample index n of ADC frames; frame index of STATUS and SPEED frames."""
        return self.nominal.seq[self.frame_uid]

    @property
    def base_id(self) -> int:
        return self.scenario.base_id

    @property
    def t0(self) -> float:
        """Time of the run's start on the frames' time base (scenario start_time_s)."""
        return fx.to_us(self.scenario.start_time_s) / 1e6

    def effect(self, index: int) -> FaultEffect:
        """The effect of the fault at 1-based position ``index`` of [[faults]]."""
        for e in (*self.effects, *self.uart_effects()):
            if e.fault.index == index:
                return e
        raise KeyError(index)

    def uart_effects(self) -> tuple[FaultEffect, ...]:
        if not any(f.target == "uart" for f in self.scenario.faults):
            return ()
        return self.uart_stream().effects

    def uart_stream(self) -> UartStream:
        """The UART byte stream (computed on first use: it encodes packets one by one)."""
        if self._uart is None:
            self._uart = _uart_stream(self)
        return self._uart

    def uart_bytes(self) -> bytes:
        return self.uart_stream().data

    def summary(self) -> str:
        sc = self.scenario
        kinds, n = np.unique(self.frame_kind, return_counts=True)
        by_kind = dict(zip(kinds.tolist(), n.tolist(), strict=True))
        lines = [summary_headline(sc, len(self.frames), by_kind)]
        lines += [f"  fault {e.describe()}" for e in self.effects]
        if self._uart is not None:
            lines += [f"  fault {e.describe()}" for e in self._uart.effects]
        else:
            lines += [
                f"  fault {f.label}: UART only (the UART stream was not generated)"
                for f in sc.faults
                if f.target == "uart"
            ]
        return "\n".join(lines)


def summary_headline(sc: Scenario, frames: int, by_kind: Mapping[int, int]) -> str:
    """The first line of a run's summary: what ran and how many frames of each kind."""
    return (
        f"{sc.source}: {sc.duration_s:g} s at {sc.sample_rate_hz} Hz, seed {sc.seed}: "
        f"{frames} frames ({by_kind.get(FrameKind.ADC, 0)} ADC, "
        f"{by_kind.get(FrameKind.STATUS, 0)} status, {by_kind.get(FrameKind.SPEED, 0)} speed)"
    )


def simulate(sc: Scenario) -> Simulation:
    """Run the scenario: world -> sensors -> ADC -> frames -> faults -> bus schedule."""
    n = sc.n_samples
    start_us = fx.to_us(sc.start_time_s)
    duration_us = fx.to_us(sc.duration_s)

    # --- the world, the sensors and the board's own faults: the engine, in one block
    block = Engine(sc).block(0, n)
    hit = {index: np.flatnonzero(mask) for index, mask in block.hit.items()}

    # --- frames of the three streams (counter jumps are part of what the sender sends)
    jumps = [f for f in sc.faults if f.kind == "counter_jump"]
    parts = [block.adc, _status_stream(sc, duration_us, jumps)]
    odometer = np.zeros(0, dtype=ODOMETER_TRUTH_DTYPE)
    if sc.speed_ref:
        speed_set, odometer = _speed_stream(sc, duration_us, jumps)
        parts.append(speed_set)
    nominal = merge(parts)
    n_nom = len(nominal)

    # --- layer 2: source faults (both links)
    alive = np.ones(n_nom, dtype=bool)
    data = nominal.data.copy()
    corrupted = np.zeros(n_nom, dtype=bool)
    removed: dict[int, np.ndarray] = {}
    crc_uids: dict[int, np.ndarray] = {}
    for f in sc.faults:
        if f.kind == "dropout":
            sel = _targeted(nominal, f) & alive
            removed[f.index] = np.flatnonzero(sel)
            alive &= ~sel
    for f in sc.faults:
        if f.kind == "crc":
            rng = fx.rng_for(sc.seed, fx.LAYER_FAULT, f.index)
            sel = fx.pick(_targeted(nominal, f) & alive & ~corrupted, f.params["probability"], rng)
            rows = np.flatnonzero(sel)
            fx.flip_bits(data, rows, rng)
            corrupted |= sel
            crc_uids[f.index] = rows
    uids = np.flatnonzero(alive)

    # --- layer 3a: duplicates take bus time, so they come before scheduling
    tag = np.zeros(len(uids), dtype=np.int64)  # fault index that made a copy, 0 = original
    for f in sc.faults:
        if f.kind == "duplicate":
            rng = fx.rng_for(sc.seed, fx.LAYER_FAULT, f.index)
            cand = _targeted(nominal, f, uids) & (tag == 0)
            order, is_copy = fx.duplicate_rows(
                len(uids), fx.pick(cand, f.params["probability"], rng)
            )
            uids, tag = uids[order], np.where(is_copy, f.index, tag[order])
    send_us = fx.serialise(nominal.queue_us[uids], sc.board.frame_gap_us)
    on_uart = (tag == 0) & (nominal.kind[uids] != FrameKind.SPEED)
    board_uid, board_send_us = uids[on_uart], send_us[on_uart]

    # --- layer 3b: the receiving adapter loses and reorders frames
    rid = np.arange(len(uids), dtype=np.int64)
    lost: dict[int, np.ndarray] = {}
    for f in sc.faults:
        if f.kind == "loss":
            rng = fx.rng_for(sc.seed, fx.LAYER_FAULT, f.index)
            sel = fx.pick(_targeted(nominal, f, uids), f.params["probability"], rng)
            lost[f.index] = uids[sel]
            keep = ~sel
            uids, tag, rid, send_us = uids[keep], tag[keep], rid[keep], send_us[keep]
    moved: dict[int, np.ndarray] = {}
    for f in sc.faults:
        if f.kind == "reorder":
            rng = fx.rng_for(sc.seed, fx.LAYER_FAULT, f.index)
            sel = fx.pick(_targeted(nominal, f, uids), f.params["probability"], rng)
            moved[f.index] = rid[sel]
            order = fx.reorder_rows(sel, f.params["depth"])
            uids, tag, rid = uids[order], tag[order], rid[order]  # times stay with the slots

    frames = np.zeros(len(uids), dtype=FRAME_DTYPE)
    frames["t"] = (start_us + send_us) / 1e6
    frames["id"] = nominal.can_id[uids]
    frames["dlc"] = FRAME_DLC
    frames["data"] = data[uids]

    # --- what each fault did, in terms of the final frames
    pos_of_rid = np.full(int(rid.max()) + 1 if len(rid) else 0, -1, dtype=np.int64)
    pos_of_rid[rid] = np.arange(len(rid))
    effects = []
    for f in sc.faults:
        if f.target == "uart":
            continue
        if f.index in hit:
            mask = _sample_mask(nominal, f, hit[f.index], n)
            eff = FaultEffect(f, _final(mask, uids), samples=hit[f.index])
        elif f.kind == "dropout":
            eff = FaultEffect(
                f, removed_uids=removed[f.index], samples=_adc_samples(nominal, removed[f.index])
            )
        elif f.kind == "crc":
            mask = np.zeros(n_nom, dtype=bool)
            mask[crc_uids[f.index]] = True
            eff = FaultEffect(
                f, _final(mask, uids), samples=_adc_samples(nominal, crc_uids[f.index])
            )
        elif f.kind == "counter_jump":
            mask = _targeted(nominal, f)
            eff = FaultEffect(
                f, _final(mask, uids), samples=_adc_samples(nominal, np.flatnonzero(mask))
            )
        elif f.kind == "duplicate":
            rows = np.flatnonzero(tag == f.index)
            eff = FaultEffect(f, rows, samples=_adc_samples(nominal, uids[rows]))
        elif f.kind == "loss":
            eff = FaultEffect(
                f, removed_uids=lost[f.index], samples=_adc_samples(nominal, lost[f.index])
            )
        else:  # reorder
            rows = np.sort(pos_of_rid[moved[f.index]])
            eff = FaultEffect(f, rows, samples=_adc_samples(nominal, uids[rows]))
        effects.append(eff)

    return Simulation(
        scenario=sc,
        frames=frames,
        frame_uid=uids,
        frame_copy=tag > 0,
        truth=block.truth,
        effects=tuple(effects),
        nominal=nominal,
        board_uid=board_uid,
        board_send_us=board_send_us,
        board_data=data[board_uid],
        odometer=odometer,
    )


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


def _sample_mask(nominal: FrameSet, f: Fault, samples: np.ndarray, n: int) -> np.ndarray:
    hit = np.zeros(n, dtype=bool)
    hit[samples] = True
    is_adc = nominal.kind == FrameKind.ADC
    chan_ok = np.isin(nominal.channel, fx.target_channels(f))
    return is_adc & chan_ok & hit[np.where(is_adc, nominal.seq, 0)]


def _final(mask_nominal: np.ndarray, uids: np.ndarray) -> np.ndarray:
    return np.flatnonzero(mask_nominal[uids])


def _adc_samples(nominal: FrameSet, uids: np.ndarray) -> np.ndarray:
    adc = nominal.kind[uids] == FrameKind.ADC
    return np.unique(nominal.seq[uids[adc]])


def _uart_stream(sim: Simulation) -> UartStream:
    try:
        from protocol.uart import encode_packet
    except ImportError as exc:  # pragma: no cover - lands with the UART codec
        raise BenchError(f"UART output needs protocol.uart.encode_packet ({exc})") from None
    sc = sim.scenario
    ids = sim.nominal.can_id[sim.board_uid].tolist()
    payload = sim.board_data.tobytes()
    bodies = [encode_packet(cid, payload[8 * k : 8 * k + 8])[:-1] for k, cid in enumerate(ids)]
    send_us = sim.board_send_us
    effects = []
    broken: set[int] = set()
    for f in sc.faults:
        if f.target != "uart":
            continue
        rng = fx.rng_for(sc.seed, fx.LAYER_UART, f.index)
        rows = np.flatnonzero(fx.pick(fx.in_window(send_us, f), f.params["probability"], rng))
        for r in rows.tolist():
            if f.kind == "noise":
                bodies[r] = fx.inject_noise(bodies[r], f.params["burst_bytes"], rng)
            else:
                bodies[r] = fx.truncate(bodies[r], rng)
        broken.update(rows.tolist())
        effects.append(FaultEffect(f, rows))
    lengths = np.fromiter((len(b) + 1 for b in bodies), dtype=np.int64, count=len(bodies))
    return UartStream(
        data=b"".join(b + b"\x00" for b in bodies),
        packet_t=(fx.to_us(sc.start_time_s) + send_us) / 1e6,
        packet_end=np.cumsum(lengths),
        packet_uid=sim.board_uid,
        broken=np.array(sorted(broken), dtype=np.int64),
        effects=tuple(effects),
    )
