"""Vectorised decode of a frame batch: the array twin of :func:`protocol.can_codec.decode`.

Returns one column per field; a column is meaningful only where ``kind`` and
``outcome`` say so (e.g. ``code`` for ADC frames with outcome OK).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocol.crc import frame_crc8_batch
from protocol.layout import DEFAULT_BASE, FRAME_DLC, SPEED_REF_ID, FrameKind, Outcome
from protocol.records import NOT_BOARD_FLAGS

# plain ints: enum member access costs more than the numpy work on a one-frame batch
_OTHER, _STATUS, _ADC, _SPEED = (int(k) for k in FrameKind)
_OK, _UNKNOWN_ID, _WRONG_DLC, _CRC_MISMATCH = (
    int(o) for o in (Outcome.OK, Outcome.UNKNOWN_ID, Outcome.WRONG_DLC, Outcome.CRC_MISMATCH)
)


@dataclass(frozen=True, slots=True)
class DecodedBatch:
    can_id: np.ndarray  # int64 arbitration id, as received
    dlc: np.ndarray  # uint8 data length, as received
    kind: np.ndarray  # uint8 FrameKind, by id
    channel: np.ndarray  # uint8 1..3 for ADC frames, else 0
    outcome: np.ndarray  # uint8 Outcome
    counter: np.ndarray  # uint8, all message types
    code: np.ndarray  # int32, ADC
    status: np.ndarray  # uint8, ADC
    timestamp: np.ndarray  # uint16, ADC and SPEED
    speed: np.ndarray  # int32 mm/s, SPEED
    state: np.ndarray  # uint8, STATUS
    sample_rate: np.ndarray  # uint16, STATUS
    temperature: np.ndarray  # int8, STATUS
    supply: np.ndarray  # uint8, STATUS
    errors: np.ndarray  # uint8, STATUS

    def __len__(self) -> int:
        return len(self.kind)

    @property
    def ok(self) -> np.ndarray:
        return self.outcome == _OK


def decode_batch(frames: np.ndarray, base: int = DEFAULT_BASE) -> DecodedBatch:
    """Decode a FRAME_DTYPE array. Pure and total: every row gets a kind and an outcome."""
    ids = frames["id"].astype(np.int64)
    d = np.ascontiguousarray(frames["data"])
    n = len(ids)
    offset = ids - base
    # the board sends only 11-bit data frames: extended, remote and error frames are foreign
    foreign = (frames["flags"] & NOT_BOARD_FLAGS) != 0
    is_adc = (offset >= 1) & (offset <= 3) & ~foreign
    is_status = (offset == 0) & ~foreign
    is_speed = (ids == SPEED_REF_ID) & ~foreign
    kind = np.full(n, _OTHER, dtype=np.uint8)
    kind[is_adc] = _ADC
    kind[is_status] = _STATUS
    kind[is_speed] = _SPEED
    channel = np.where(is_adc & ~is_speed, offset, 0).astype(np.uint8)

    outcome = np.full(n, _OK, dtype=np.uint8)
    crc_ok = frame_crc8_batch(ids, d) == d[:, 7]
    outcome[~crc_ok] = _CRC_MISMATCH
    outcome[frames["dlc"] != FRAME_DLC] = _WRONG_DLC
    outcome[kind == _OTHER] = _UNKNOWN_ID

    d32 = d.astype(np.int32)
    code24 = d32[:, 1] | (d32[:, 2] << 8) | (d32[:, 3] << 16)
    code = np.where(code24 & 0x800000, code24 - (1 << 24), code24).astype(np.int32)
    ts = (d32[:, 5] | (d32[:, 6] << 8)).astype(np.uint16)
    u32 = d.astype(np.uint32)
    speed = (u32[:, 1] | (u32[:, 2] << 8) | (u32[:, 3] << 16) | (u32[:, 4] << 24)).view(np.int32)
    return DecodedBatch(
        can_id=ids,
        dlc=frames["dlc"].copy(),
        kind=kind,
        channel=channel,
        outcome=outcome,
        counter=d[:, 0].copy(),
        code=code,
        status=d[:, 4].copy(),
        timestamp=ts,
        speed=speed,
        state=d[:, 1].copy(),
        sample_rate=(d32[:, 2] | (d32[:, 3] << 8)).astype(np.uint16),
        temperature=d[:, 4].view(np.int8).copy(),
        supply=d[:, 5].copy(),
        errors=d[:, 6].copy(),
    )
