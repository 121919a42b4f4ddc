"""Array layouts of the board-status and speed-reference streams as they pass the pipeline."""

from __future__ import annotations

import numpy as np

from protocol.batch import DecodedBatch
from protocol.layout import FrameKind, Outcome

_STATUS, _SPEED, _OK = int(FrameKind.STATUS), int(FrameKind.SPEED), int(Outcome.OK)

STATUS_DTYPE = np.dtype(
    [
        ("seq", "<i8"),
        ("t", "<f8"),
        ("counter", "u1"),
        ("state", "u1"),
        ("sample_rate", "<u2"),
        ("temperature", "i1"),
        ("supply", "u1"),
        ("errors", "u1"),
    ]
)

SPEED_DTYPE = np.dtype(
    [("seq", "<i8"), ("t", "<f8"), ("counter", "u1"), ("speed", "<i4"), ("timestamp", "<u2")]
)


def status_records(t: np.ndarray, dec: DecodedBatch, seq0: int) -> np.ndarray:
    idx = np.flatnonzero((dec.kind == _STATUS) & (dec.outcome == _OK))
    out = np.zeros(len(idx), dtype=STATUS_DTYPE)
    out["seq"] = seq0 + idx
    out["t"] = t[idx]
    for name in ("counter", "state", "sample_rate", "temperature", "supply", "errors"):
        out[name] = getattr(dec, name)[idx]
    return out


def speed_records(t: np.ndarray, dec: DecodedBatch, seq0: int) -> np.ndarray:
    idx = np.flatnonzero((dec.kind == _SPEED) & (dec.outcome == _OK))
    out = np.zeros(len(idx), dtype=SPEED_DTYPE)
    out["seq"] = seq0 + idx
    out["t"] = t[idx]
    out["counter"] = dec.counter[idx]
    out["speed"] = dec.speed[idx]
    out["timestamp"] = dec.timestamp[idx]
    return out
