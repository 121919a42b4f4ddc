"""Shared helpers of the MCAP tests: a synthetic ACB-3 stream with every fault kind, built
from protocol.can_codec (independent of the emulator), and a pipeline runner.

Also tests the helpers themselves, so a broken generator fails here and not as a puzzling
mismatch elsewhere.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.config import Config
from bench.pipeline.steps import Pipeline, StepOutput
from bench.records.results import RESULT_DTYPE
from bench.sinks.tables import results_csv_text
from devices.base import SourceBatch, SourceNotice
from protocol.can_codec import encode_adc, encode_speed, encode_status
from protocol.frames import FRAME_DTYPE
from protocol.layout import DEFAULT_BASE, G0, NOMINAL_ANGLES_DEG, NOMINAL_SCALE, Outcome
from protocol.records import FLAG_UART, AdcSample, BoardStatus, LinkError, SpeedRef


@dataclass
class Stream:
    """A synthetic run: frames in arrival order, cut into source batches."""

    batches: list[SourceBatch]
    frames: np.ndarray
    link_errors: list[LinkError] = field(default_factory=list)
    notices: list[SourceNotice] = field(default_factory=list)

    def counts_by_id(self) -> Counter[int]:
        return Counter(self.frames["id"].tolist())


def csv_text(results: np.ndarray) -> str:
    """Results as the CSV `bench replay --csv` writes (the text two runs must agree on)."""
    return results_csv_text(results)


def _us(t: float) -> float:
    """Whole microseconds, as the emulator times are (ARCHITECTURE.md conventions)."""
    return round(t * 1e6) / 1e6


def synthetic_stream(
    seconds: float = 2.0,
    rate_hz: int = 200,
    *,
    seed: int = 7,
    faults: bool = True,
    t0: float = 1_700_000_000.0,
    base: int = DEFAULT_BASE,
    batch_frames: int = 37,
) -> Stream:
    """ADC frames for 3 channels on a 12 per mille grade, status at 10 Hz, speed at 50 Hz.

    With ``faults``: CRC corruption, wrong DLC, unknown IDs, status fault bits, dropped,
    duplicated and swapped frames, frames flagged as arrived on the UART, UART link errors
    of every kind, and a disconnect/reconnect notice pair.
    """
    rng = np.random.default_rng(seed)
    alpha = math.atan(12e-3)
    rows: list[tuple[float, int, bytes, int]] = []
    errors: list[LinkError] = []
    n = int(seconds * rate_hz)
    for k in range(n):
        t = t0 + k / rate_hz
        ts = round(k * 10000 / rate_hz) & 0xFFFF
        for ch in (1, 2, 3):
            theta = math.radians(NOMINAL_ANGLES_DEG[ch - 1])
            accel = 0.05 * math.sin(2 * math.pi * 0.5 * (t - t0))  # the train, m/s^2
            a = accel * math.cos(theta) + G0 * math.sin(alpha + theta)  # ICD section 3
            code = round(a / NOMINAL_SCALE + rng.normal(0, 3))
            status = 0
            if faults and rng.random() < 0.01:
                status = int(rng.choice([1, 2, 4, 8]))
            cid, data = encode_adc(AdcSample(ch, k & 0xFF, code, status, ts), base)
            flags = FLAG_UART if faults and rng.random() < 0.05 else 0
            tt = _us(t + ch * 150e-6)
            if faults:
                r = rng.random()
                if r < 0.01:
                    continue  # dropped
                if r < 0.02:
                    data = bytes([data[0] ^ 0x40, *data[1:]])  # CRC mismatch
                elif r < 0.025:
                    data = data[:6]  # wrong DLC
                elif r < 0.03:
                    rows.append((tt, cid, data, flags))  # duplicate
            rows.append((tt, cid, data, flags))
        if k % (rate_hz // 10) == 0:
            cid, data = encode_status(
                BoardStatus(k // (rate_hz // 10) & 0xFF, 1, rate_hz, 31, 240, 0), base
            )
            rows.append((_us(t + 700e-6), cid, data, 0))
        if k % (rate_hz // 50) == 0:
            cid, data = encode_speed(SpeedRef(k // (rate_hz // 50) & 0xFF, 22_222, ts))
            rows.append((_us(t + 800e-6), cid, data, 0))
        if faults and rng.random() < 0.02:
            rows.append((_us(t + 900e-6), 0x7FF, bytes(rng.integers(0, 256, 8, dtype=np.uint8)), 0))
        if faults and rng.random() < 0.02:
            kind = [Outcome.COBS_ERROR, Outcome.CRC16_ERROR, Outcome.LENGTH_ERROR][k % 3]
            raw = bytes(rng.integers(0, 256, int(rng.integers(1, 20)), dtype=np.uint8))
            errors.append(LinkError(_us(t + 950e-6), kind, raw, f"synthetic {kind.name}"))
    if faults:  # a few swapped neighbours: reordering on the bus
        for i in rng.integers(10, len(rows) - 10, 5):
            rows[i], rows[i + 1] = rows[i + 1], rows[i]
    frames = np.zeros(len(rows), dtype=FRAME_DTYPE)
    frames["t"] = [r[0] for r in rows]
    frames["id"] = [r[1] for r in rows]
    frames["dlc"] = [len(r[2]) for r in rows]
    frames["flags"] = [r[3] for r in rows]
    frames["data"] = (
        np.array([r[2].ljust(8, b"\0") for r in rows], dtype="S8").view(np.uint8).reshape(-1, 8)
    )
    notices = []
    if faults:
        mid = float(frames["t"][len(frames) // 2])
        notices = [
            SourceNotice(mid, "disconnect", "synthetic unplug"),
            SourceNotice(mid + 0.001, "reconnect", ""),
        ]
    batches = _cut(frames, errors, notices, batch_frames, rng)
    return Stream(batches, frames, errors, notices)


def _cut(
    frames: np.ndarray,
    errors: list[LinkError],
    notices: list[SourceNotice],
    batch_frames: int,
    rng: np.random.Generator,
) -> list[SourceBatch]:
    """Cut into batches of varying size; link errors and notices go with the batch whose
    frames reach their time (as a live source would deliver them)."""
    out: list[SourceBatch] = []
    i = 0
    ei = ni = 0
    while i < len(frames):
        k = int(rng.integers(1, 2 * batch_frames))
        part = frames[i : i + k]
        i += k
        last_t = float(part["t"].max())
        le = []
        while ei < len(errors) and (errors[ei].t <= last_t or i >= len(frames)):
            le.append(errors[ei])
            ei += 1
        no = []
        while ni < len(notices) and (notices[ni].t <= last_t or i >= len(frames)):
            no.append(notices[ni])
            ni += 1
        out.append(SourceBatch(part, le, no))
    if ei < len(errors) or ni < len(notices):
        out.append(SourceBatch(link_errors=errors[ei:], notices=notices[ni:]))
    return out


def run_pipeline(
    batches: Sequence[SourceBatch], config: Config | None = None, sinks: Sequence[object] = ()
) -> tuple[np.ndarray, list[StepOutput]]:
    """Run batches through a fresh Pipeline, handing every step to the sinks (as live does)."""
    pipe = Pipeline(config or Config())
    steps = []
    for batch in batches:
        steps.append(pipe.process(batch))
    steps.append(pipe.finish())
    for step in steps:
        for sink in sinks:
            sink.write(step)  # type: ignore[attr-defined]
    results = [s.results for s in steps if len(s.results)]
    return (np.concatenate(results) if results else np.zeros(0, RESULT_DTYPE)), steps


ALL_EMULATOR_FAULTS: list[dict[str, object]] = [
    {"channel": 1, "kind": "stuck", "start_s": 2.0, "end_s": 3.0},
    {"channel": 2, "kind": "drift", "start_s": 3.0, "end_s": 5.0},
    {"channel": 3, "kind": "spike", "start_s": 5.0, "end_s": 7.0},
    {"channel": 1, "kind": "saturate", "start_s": 7.0, "end_s": 7.5},
    {"channel": 2, "kind": "status", "start_s": 8.0, "end_s": 8.5},
    {"channel": 3, "kind": "dropout", "start_s": 9.0, "end_s": 9.5},
    {"channel": "bus", "kind": "crc", "probability": 0.01},
    {"channel": "bus", "kind": "loss", "probability": 0.01},
    {"channel": "bus", "kind": "duplicate", "probability": 0.01},
    {"channel": "bus", "kind": "reorder", "probability": 0.01},
    {"channel": "adc", "kind": "counter_jump", "start_s": 12.0, "end_s": 12.5, "jump": -3},
    {"channel": "uart", "kind": "noise", "probability": 0.005},
    {"channel": "uart", "kind": "truncation", "probability": 0.005},
]
"""One fault of every kind the emulator has (docs/EMULATOR.md)."""


def emulated(seconds: float = 15.0, *, seed: int = 5, faults: bool = True) -> Any:
    """An emulator Simulation on a 5 per mille grade with every fault kind enabled."""
    from devices.emulator import scenario_from_dict, simulate

    scenario = {
        "seed": seed,
        "duration_s": seconds,
        "initial_speed_mps": 10.0,
        "track": [{"length_m": 100.0, "gradient_permil": 5.0}],
        "faults": ALL_EMULATOR_FAULTS if faults else [],
    }
    return simulate(scenario_from_dict(scenario, "mcap-test"))


def uart_batches(sim: Any, packets_per_batch: int = 300) -> list[SourceBatch]:
    """The emulator's UART byte stream as a serial receiver sees it (the acceptance
    runner's feed: packet by packet at its send time, FLAG_UART frames, link errors)."""
    from bench.acceptance.feeds import uart_batches as feed

    return list(feed(sim, packets_per_batch))


def test_synthetic_stream_has_every_fault_kind() -> None:
    from protocol.batch import decode_batch

    s = synthetic_stream(seconds=3.0)
    dec = decode_batch(s.frames)
    outcomes = set(dec.outcome.tolist())
    assert {Outcome.OK, Outcome.CRC_MISMATCH, Outcome.WRONG_DLC, Outcome.UNKNOWN_ID} <= outcomes
    assert {e.outcome for e in s.link_errors} == {
        Outcome.COBS_ERROR,
        Outcome.CRC16_ERROR,
        Outcome.LENGTH_ERROR,
    }
    assert np.any(s.frames["flags"] & FLAG_UART)
    assert sum(len(b.frames) for b in s.batches) == len(s.frames)
    assert sum(len(b.link_errors) for b in s.batches) == len(s.link_errors)
    assert {n.kind for n in s.notices} == {"disconnect", "reconnect"}


def test_synthetic_stream_fuses_to_the_grade() -> None:
    s = synthetic_stream(seconds=1.0, faults=False)
    results, _ = run_pipeline(s.batches)
    assert len(results) == 200
    grad = results["gradient"][results["valid"]]
    assert abs(float(np.median(grad)) - 12.0) < 0.5


def test_emulated_uart_run_has_link_errors_and_uart_frames() -> None:
    batches = uart_batches(emulated(13.0))
    frames = np.concatenate([b.frames for b in batches])
    assert np.all(frames["flags"] & FLAG_UART)
    assert sum(len(b.link_errors) for b in batches) > 0
