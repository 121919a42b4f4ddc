"""Frame-building helpers for tests: hand-made ACB-3 frames, independent of the emulator."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from devices.base import LiveSource, SourceBatch
from protocol.batch import decode_batch
from protocol.can_codec import encode_adc, encode_status
from protocol.frames import frames_from_raw
from protocol.layout import DEFAULT_BASE, NOMINAL_SCALE, FrameKind, Outcome
from protocol.records import AdcSample, BoardStatus, RawFrame, Record, SpeedRef


def adc(
    ch: int, counter: int, code: int, ts: int, t: float, status: int = 0, base: int = DEFAULT_BASE
) -> RawFrame:
    can_id, data = encode_adc(AdcSample(ch, counter % 256, code, status, ts % 65536), base)
    return RawFrame(t, can_id, data)


def status_frame(rate: int, t: float, counter: int = 0, base: int = DEFAULT_BASE) -> RawFrame:
    can_id, data = encode_status(BoardStatus(counter % 256, 1, rate, 25, 120, 0), base)
    return RawFrame(t, can_id, data)


def instant(
    k: int,
    codes: tuple[int, int, int] = (100, 200, 300),
    rate: int = 200,
    t0: float = 0.0,
    counter0: int = 0,
    ts0: int = 0,
) -> list[RawFrame]:
    """The three frames of sampling instant k, ch1 first, at `rate` Hz."""
    period_ticks = 10000 // rate
    ts = ts0 + k * period_ticks
    t = t0 + k / rate
    return [adc(ch, counter0 + k, codes[ch - 1], ts, t + ch * 1e-4) for ch in (1, 2, 3)]


def pack(frames: list[RawFrame]) -> np.ndarray:
    return frames_from_raw(frames)


def read_until(
    src: LiveSource, done: Callable[[list[SourceBatch]], bool], timeout: float = 5.0
) -> list[SourceBatch]:
    """Read a live source until ``done(batches)`` or the timeout; every non-empty batch kept."""
    batches: list[SourceBatch] = []
    deadline = time.monotonic() + timeout
    while not done(batches) and time.monotonic() < deadline:
        batch = src.read(0.05)
        if batch:
            batches.append(batch)
    return batches


ROOT = Path(__file__).resolve().parent.parent


def bench(*args: str, timeout: float = 120.0, **kw: Any) -> subprocess.CompletedProcess[str]:
    """``python -m bench ARGS`` in a process of its own (from the repo root unless ``cwd``
    says otherwise), its output captured; the timeout only ends a hang."""
    kw.setdefault("cwd", ROOT)
    cmd = [sys.executable, "-m", "bench", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False, **kw)


def event_texts(path: Path) -> list[str]:
    """The text of every /bench/events message of an MCAP file, read with the mcap
    package's own reader (not the bench's)."""
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return [
            json.loads(m.data)["message"]
            for _s, _c, m in make_reader(f).iter_messages(topics=["/bench/events"])
        ]


def _toml_value(v: Any) -> str:
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    return repr(v)


def scenario_toml(d: dict[str, Any]) -> str:
    """The scenario dict as TOML (scalars, then arrays of tables)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in d.items() if not isinstance(v, list)]
    for key, items in d.items():
        if isinstance(items, list):
            for item in items:
                lines.append(f"[[{key}]]")
                lines += [f"{k} = {_toml_value(v)}" for k, v in item.items()]
    return "\n".join(lines) + "\n"


def until(cond: Callable[[], bool], what: str = "the condition", timeout: float = 60.0) -> None:
    """Poll ``cond`` until it holds; a hang guard of ``timeout`` s, not a speed bound."""
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.02)


def assemble(
    frames: list[RawFrame], rate: int = 200, cut: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(samples, events) of frames through an Assembler at ``rate``, pushed ``cut`` frames
    at a time (None: all at once), then finished."""
    from bench.pipeline.assembly import Assembler
    from protocol.batch import decode_batch

    arr = pack(frames)
    asm = Assembler(rate)
    outs, evs = [], []
    step = cut or len(arr)
    for pos in range(0, len(arr), step):
        part = arr[pos : pos + step]
        s, e = asm.push(part["t"], decode_batch(part), pos)
        outs.append(s)
        evs.append(e)
    s, e = asm.finish()
    return np.concatenate([*outs, s]), np.concatenate([*evs, e])


def kinds(events: np.ndarray, kind: int) -> np.ndarray:
    """The events of one kind."""
    return events[events["kind"] == kind]


def adc_values(frames: np.ndarray) -> np.ndarray:
    """(n, 3) accelerations (m/s^2) of an emulated run's ADC frames at the nominal scale
    (fault-free runs: the frames come in sample order, ch1, ch2, ch3)."""
    rows = [r.code * NOMINAL_SCALE for r in records(frames) if isinstance(r, AdcSample)]
    return np.array(rows).reshape(-1, 3)


# -- frames as typed records, for reading a test's expectations off them -------------------------
@dataclass(frozen=True, slots=True)
class DecodeError:
    """A frame the bench decodes to no value: ``outcome`` says why."""

    outcome: Outcome
    can_id: int


class UnknownId(DecodeError):
    pass


class WrongDlc(DecodeError):
    pass


class CrcMismatch(DecodeError):
    pass


_ERRORS = {
    Outcome.UNKNOWN_ID: UnknownId,
    Outcome.WRONG_DLC: WrongDlc,
    Outcome.CRC_MISMATCH: CrcMismatch,
}


def records(frames: np.ndarray, base: int = DEFAULT_BASE) -> list[Record | DecodeError]:
    """A FRAME_DTYPE array through the bench's one decoder (protocol.batch), a typed record
    (or the failure) per frame: the tests compare them with the ICD's values."""
    d = decode_batch(frames, base)
    out: list[Record | DecodeError] = []
    for i in range(len(d)):
        outcome = Outcome(int(d.outcome[i]))
        kind = FrameKind(int(d.kind[i]))
        counter = int(d.counter[i])
        if outcome is not Outcome.OK:
            out.append(_ERRORS[outcome](outcome, int(d.can_id[i])))
        elif kind is FrameKind.ADC:
            out.append(
                AdcSample(
                    int(d.channel[i]),
                    counter,
                    int(d.code[i]),
                    int(d.status[i]),
                    int(d.timestamp[i]),
                )
            )
        elif kind is FrameKind.STATUS:
            status = (d.state, d.sample_rate, d.temperature, d.supply, d.errors)
            out.append(BoardStatus(counter, *(int(c[i]) for c in status)))
        else:
            out.append(SpeedRef(counter, int(d.speed[i]), int(d.timestamp[i])))
    return out


def decode(
    can_id: int, data: bytes, base: int = DEFAULT_BASE, flags: int = 0
) -> Record | DecodeError:
    """One frame as :func:`records` gives it."""
    return records(frames_from_raw([RawFrame(0.0, can_id, data, flags)]), base)[0]
