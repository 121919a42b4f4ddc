"""simulate(scenario) -> Simulation: every frame the virtual board run sends, its truth and
what each fault did. Pure and deterministic: the same scenario (seed included) gives the
same frames bit for bit.

Send times are whole microseconds (``t = us / 1e6``) so that a candump text log, which
prints six decimals, parses back to the identical float64.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.board import FrameSet
from devices.emulator.scenario import Fault, Scenario
from devices.emulator.stream import (
    _EMPTY,
    ODOMETER_TRUTH_DTYPE,
    FaultEffect,
    Kept,
    RunCounts,
    _Run,
    _targeted,
    uart_packets,
)
from protocol.layout import FrameKind


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
        kinds, n = np.unique(self.frame_kind, return_counts=True)
        counts = RunCounts(self.scenario, dict(zip(kinds.tolist(), n.tolist(), strict=True)))
        counts.frames, counts.uart = len(self.frames), self._uart is not None
        for e in (*self.effects, *(self._uart.effects if self._uart else ())):
            counts.add(e.fault.index, changed=len(e.frames), removed=len(e.removed_uids))
        return counts.summary()


def simulate(sc: Scenario) -> Simulation:
    """Run the scenario: world -> sensors -> ADC -> frames -> faults -> bus schedule, as one
    chunk of the chunked run, keeping what each fault did."""
    n = sc.n_samples
    kept = Kept()
    run = _Run(sc, False, 0.0, None, None, None, kept)
    block, nominal = run.nominal(0, n, None, None)
    frames = run.frames(nominal, block.hit, n)
    uids, tag, rid = kept.rows["uid"], kept.rows["tag"], kept.rows["rid"]
    hit = {index: np.flatnonzero(mask) for index, mask in block.hit.items()}

    # --- what each fault did, in terms of the final frames
    pos_of_rid = np.full(int(rid.max()) + 1 if len(rid) else 0, -1, dtype=np.int64)
    pos_of_rid[rid] = np.arange(len(rid))
    moved = {r.fault.index: np.concatenate([_EMPTY, *(r.picked or ())]) for r in run.reorders}
    effects = []
    for f in sc.faults:
        if f.target == "uart":
            continue
        if f.index in hit:
            mask = _sample_mask(nominal, f, hit[f.index], n)
            eff = FaultEffect(f, _final(mask, uids), samples=hit[f.index])
        elif f.kind in ("dropout", "loss"):
            gone = (kept.removed if f.kind == "dropout" else kept.lost)[f.index]
            eff = FaultEffect(f, removed_uids=gone, samples=_adc_samples(nominal, gone))
        elif f.kind in ("crc", "counter_jump"):
            mask = kept.crc[f.index] if f.kind == "crc" else _targeted(nominal, f)
            eff = FaultEffect(
                f, _final(mask, uids), samples=_adc_samples(nominal, np.flatnonzero(mask))
            )
        else:  # duplicate, reorder
            if f.kind == "duplicate":
                rows = np.flatnonzero(tag == f.index)
            else:
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
        board_uid=kept.board_uid,
        board_send_us=kept.board_send_us,
        board_data=kept.data[kept.board_uid],
        odometer=run.odometer,
    )


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
    sc = sim.scenario
    rng = {f.index: fx.rng_for(sc.seed, fx.LAYER_UART, f.index) for f in sc.faults}
    ids = sim.nominal.can_id[sim.board_uid]
    bodies, broken = uart_packets(sc, ids, sim.board_data, sim.board_send_us, rng, rng)
    lengths = np.fromiter((len(b) + 1 for b in bodies), dtype=np.int64, count=len(bodies))
    return UartStream(
        data=b"".join(b + b"\x00" for b in bodies),
        packet_t=(fx.to_us(sc.start_time_s) + sim.board_send_us) / 1e6,
        packet_end=np.cumsum(lengths),
        packet_uid=sim.board_uid,
        broken=np.unique(np.concatenate([_EMPTY, *broken.values()])),
        effects=tuple(FaultEffect(f, broken[f.index]) for f in sc.faults if f.target == "uart"),
    )
