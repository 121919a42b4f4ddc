"""What an emulated acceptance run feeds the pipeline (the virtual board's CAN frames or UART
bytes as a receiver sees them) and the emulator's record of what each fault did."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from bench.acceptance.model import FaultInfo
from devices.base import SourceBatch

BATCH_FRAMES = 65536


def can_batches(frames: np.ndarray, size: int = BATCH_FRAMES) -> Iterator[SourceBatch]:
    for i in range(0, len(frames), size):
        yield SourceBatch(frames[i : i + size])


def uart_batches(sim: Any, packets_per_batch: int = 2048) -> Iterator[SourceBatch]:
    """The UART byte stream as a receiver sees it: packet by packet at its send time, so
    frames get receive times and broken packets become link errors at their own time."""
    from protocol.frames import frames_from_raw
    from protocol.uart import Deframer

    stream = sim.uart_stream()
    data, ends, times = stream.data, stream.packet_end, stream.packet_t
    de = Deframer()
    start = 0
    for i0 in range(0, len(ends), packets_per_batch):
        raw: list[Any] = []
        errors: list[Any] = []
        for i in range(i0, min(i0 + packets_per_batch, len(ends))):
            end = int(ends[i])
            fr, er = de.feed(data[start:end], float(times[i]))
            raw += fr
            errors += er
            start = end
        yield SourceBatch(frames_from_raw(raw), errors)
    tail_frames, tail_errors = de.feed(data[start:], float(times[-1]) if len(times) else 0.0)
    _, flushed = de.flush()
    if tail_frames or tail_errors or flushed:
        yield SourceBatch(frames_from_raw(tail_frames), tail_errors + flushed)


def fault_infos(sim: Any, link: str) -> tuple[FaultInfo, ...]:
    """The emulator's record of what each fault did, as the checks need it."""
    from devices.emulator.faults import target_channels

    effects = list(sim.effects)
    if link == "uart":
        effects += list(sim.uart_effects())
    out = []
    for e in sorted(effects, key=lambda e: e.fault.index):
        f = e.fault
        onset = int(np.min(e.samples)) if len(e.samples) else None
        out.append(
            FaultInfo(
                f.index, f.kind, target_channels(f), f.label, f.start_s, f.end_s, onset, e.count
            )
        )
    return tuple(out)
