"""Decode of a frame batch (ICD section 1), the bench's one decoder, one column a field.

Returns one column per field; a column is meaningful only where ``kind`` and
``outcome`` say so (e.g. ``code`` for ADC frames with outcome OK).

One path for any batch length, a live step of one frame or a log's 65 536: strided views
straight into the frame records (one pass per field, CRC two bytes per table lookup).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocol.crc import frame_crc8_residue
from protocol.frames import FRAME_DTYPE
from protocol.layout import DEFAULT_BASE, FRAME_DLC, SPEED_REF_ID, FrameKind, Outcome
from protocol.records import NOT_BOARD_FLAGS

# plain ints for the lookup tables below
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
        ok: np.ndarray = self.outcome == _OK
        return ok


# -- strided views into the frame records -------------------------------------------------
_OFFSET = {name: spec[1] for name, spec in (FRAME_DTYPE.fields or {}).items()}


def _at(name: str, fmt: str, byte: int) -> tuple[str, str, int]:
    return name, fmt, _OFFSET["data"] + byte


_FIELDS = [
    ("id", "<u4", _OFFSET["id"]),
    ("id16", "<u2", _OFFSET["id"]),
    ("dlc", "u1", _OFFSET["dlc"]),
    ("flags", "u1", _OFFSET["flags"]),
    _at("counter", "u1", 0),
    _at("state", "u1", 1),
    _at("code_le", "<u4", 1),  # bytes 1..3 code, byte 4 above it
    _at("speed", "<i4", 1),
    _at("sample_rate", "<u2", 2),
    _at("status", "u1", 4),
    _at("temperature", "i1", 4),
    _at("timestamp", "<u2", 5),
    _at("supply", "u1", 5),
    _at("errors", "u1", 6),
    _at("w01", "<u2", 0),
    _at("w23", "<u2", 2),
    _at("w45", "<u2", 4),
    _at("w67", "<u2", 6),
]
_VIEW = np.dtype(
    {
        "names": [f[0] for f in _FIELDS],
        "formats": [f[1] for f in _FIELDS],
        "offsets": [f[2] for f in _FIELDS],
        "itemsize": FRAME_DTYPE.itemsize,
    }
)
"""Overlapping little-endian fields of a frame record: each field one strided read."""

# class of a frame: 0 status, 1..3 ADC channel, 4 other, 5 speed reference
_KIND_OF_CLASS = np.array([_STATUS, _ADC, _ADC, _ADC, _OTHER, _SPEED], dtype=np.uint8)
_CHANNEL_OF_CLASS = np.array([0, 1, 2, 3, 0, 0], dtype=np.uint8)
# outcome by (unknown id, wrong dlc, bad crc) bits 2, 1, 0: the first failure wins
_OUTCOME_OF_BITS = np.array(
    [_OK, _CRC_MISMATCH, _WRONG_DLC, _WRONG_DLC] + [_UNKNOWN_ID] * 4, dtype=np.uint8
)


def decode_batch(frames: np.ndarray, base: int = DEFAULT_BASE) -> DecodedBatch:
    """Decode a FRAME_DTYPE array. Pure and total: every row gets a kind and an outcome."""
    if frames.dtype != FRAME_DTYPE:
        frames = frames.astype(FRAME_DTYPE)
    v = frames.view(_VIEW)
    ids = v["id"].astype(np.int64)
    cls = np.minimum((ids - base).view(np.uint64), 4)  # ids below base wrap to huge
    cls[ids == SPEED_REF_ID] = 5
    cls[(v["flags"] & NOT_BOARD_FLAGS) != 0] = 4  # extended, remote, error: not the board's
    kind = _KIND_OF_CLASS[cls]
    dlc = v["dlc"].copy()
    bits = (frame_crc8_residue((v["id16"], v["w01"], v["w23"], v["w45"], v["w67"])) != 0).view(
        np.uint8
    )
    bits |= (dlc != FRAME_DLC).view(np.uint8) << 1
    bits |= (kind == _OTHER).view(np.uint8) << 2
    return DecodedBatch(
        can_id=ids,
        dlc=dlc,
        kind=kind,
        channel=_CHANNEL_OF_CLASS[cls],
        outcome=_OUTCOME_OF_BITS[bits],
        counter=v["counter"].copy(),
        code=(v["code_le"] << 8).view(np.int32) >> 8,  # sign-extend the 24-bit code
        status=v["status"].copy(),
        timestamp=v["timestamp"].copy(),
        speed=v["speed"].copy(),
        state=v["state"].copy(),
        sample_rate=v["sample_rate"].copy(),
        temperature=v["temperature"].copy(),
        supply=v["supply"].copy(),
        errors=v["errors"].copy(),
    )


EMPTY_DECODED = decode_batch(np.zeros(0, dtype=FRAME_DTYPE))
"""The decode of no frames, for a step that has none."""
