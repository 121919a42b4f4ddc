"""Recorded replay inputs back into what a source yields: raw-frame records to FRAME_DTYPE
rows, JSON link errors and notices to their records."""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from devices.base import SourceNotice
from protocol.frames import FRAME_DTYPE, empty_frames
from protocol.layout import Outcome
from protocol.records import LinkError


def frames_from_records(recs: np.ndarray) -> np.ndarray:
    """FRAME_DTYPE rows of raw-frame records."""
    p = recs["payload"]
    out = np.empty(len(recs), dtype=FRAME_DTYPE)
    out["t"] = p["t"]
    out["id"] = p["id"]
    out["dlc"] = np.minimum(p["dlc"], 255)
    out["flags"] = p["flags"] & 0xFF  # above bit 7: bench marks (FLAG_BATCH_START)
    out["data"] = p["data"]
    return out


def concat_frames(parts: list[np.ndarray]) -> np.ndarray:
    if not parts:
        return empty_frames()
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def json_float(v: Any) -> float:
    return float("nan") if v is None else float(v)


def link_error_from_json(m: bytes | memoryview) -> LinkError:
    d = json.loads(bytes(m))
    code = int(d.get("outcome", 0))
    outcome: Outcome | int = Outcome(code) if code in Outcome._value2member_map_ else code
    return LinkError(
        json_float(d.get("t")),
        outcome,  # type: ignore[arg-type]  # a code this bench does not know stays the int it is
        base64.b64decode(d.get("raw", "")),
        d.get("detail", ""),
    )


def notice_from_json(m: bytes | memoryview) -> SourceNotice:
    d = json.loads(bytes(m))
    return SourceNotice(
        json_float(d.get("t")),
        str(d.get("kind", "")),
        str(d.get("detail", "")),
        int(d.get("count") or 0),  # absent in logs written before it existed
    )


def or_notice(
    conv: Callable[[bytes | memoryview], LinkError | SourceNotice], where: str
) -> Callable[[bytes | memoryview], LinkError | SourceNotice]:
    """``conv``, or a parse_error notice for a message that is not the JSON ``conv`` reads
    (a damaged file whose channel ids or payloads changed): counted, never a traceback."""

    def one(m: bytes | memoryview) -> LinkError | SourceNotice:
        try:
            return conv(m)
        except (ValueError, TypeError, AttributeError) as exc:
            why = f"{type(exc).__name__}: {exc}"[:120]
            return SourceNotice(math.nan, "parse_error", f"{where}: message skipped ({why})")

    return one
