"""The frame batch: many raw CAN frames in one numpy structured array.

Every source hands the pipeline frames in this layout (a burst from a live bus, or a
million rows from a log), so decoding and assembly run vectorised either way.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from protocol.records import RawFrame

FRAME_DTYPE = np.dtype(
    [
        ("t", "<f8"),  # receive time, s (NaN when the medium carries none)
        ("id", "<u4"),  # arbitration id
        ("dlc", "u1"),  # data length as received (may exceed 8 for CAN FD; data holds 8)
        ("flags", "u1"),  # protocol.records.FLAG_* bits
        ("data", "u1", (8,)),  # payload, zero padded
    ]
)


def empty_frames(n: int = 0) -> np.ndarray:
    return np.zeros(n, dtype=FRAME_DTYPE)


def frames_from_raw(frames: Iterable[RawFrame]) -> np.ndarray:
    """Pack RawFrames into a FRAME_DTYPE array (payloads beyond 8 bytes are cut, dlc kept)."""
    rows = list(frames)
    out = np.zeros(len(rows), dtype=FRAME_DTYPE)
    if not rows:
        return out
    out["t"] = [f.t for f in rows]
    out["id"] = [f.can_id for f in rows]
    out["dlc"] = [min(len(f.data), 255) for f in rows]
    out["flags"] = [f.flags for f in rows]
    padded = b"".join(bytes(f.data[:8]).ljust(8, b"\0") for f in rows)
    out["data"] = np.frombuffer(padded, dtype=np.uint8).reshape(-1, 8)
    return out
