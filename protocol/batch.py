"""Vectorised decode of a frame batch: the array twin of :func:`protocol.can_codec.decode`.

Returns one column per field; a column is meaningful only where ``kind`` and
``outcome`` say so (e.g. ``code`` for ADC frames with outcome OK).

Two paths give the same columns: a live batch of a few frames is decoded in plain Python
(numpy's fixed cost per call would dominate), a log's batch by strided views straight
into the frame records (one pass per field, CRC two bytes per table lookup).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from protocol.crc import _CRC8_TABLE, frame_crc8_residue
from protocol.frames import FRAME_DTYPE
from protocol.layout import DEFAULT_BASE, FRAME_DLC, SPEED_REF_ID, FrameKind, Outcome
from protocol.records import NOT_BOARD_FLAGS

# plain ints: enum member access costs more than the numpy work on a one-frame batch
_OTHER, _STATUS, _ADC, _SPEED = (int(k) for k in FrameKind)
_OK, _UNKNOWN_ID, _WRONG_DLC, _CRC_MISMATCH = (
    int(o) for o in (Outcome.OK, Outcome.UNKNOWN_ID, Outcome.WRONG_DLC, Outcome.CRC_MISMATCH)
)

SCALAR_MAX = 16
"""Batches up to this many frames take the scalar path; the columns are the same."""

DECODED_DTYPE = np.dtype(
    [
        ("can_id", "<i8"),
        ("dlc", "u1"),
        ("kind", "u1"),
        ("channel", "u1"),
        ("outcome", "u1"),
        ("counter", "u1"),
        ("code", "<i4"),
        ("status", "u1"),
        ("timestamp", "<u2"),
        ("speed", "<i4"),
        ("state", "u1"),
        ("sample_rate", "<u2"),
        ("temperature", "i1"),
        ("supply", "u1"),
        ("errors", "u1"),
    ]
)
"""One decoded frame as a record (the scalar path builds its columns from these)."""


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


def _columns(records: np.ndarray) -> DecodedBatch:
    return DecodedBatch(*(records[name] for name in DECODED_DTYPE.names or ()))


EMPTY_DECODED = _columns(np.zeros(0, dtype=DECODED_DTYPE))
"""The decode of no frames (shared: zero-length columns cannot be written to)."""


def decode_batch(frames: np.ndarray, base: int = DEFAULT_BASE) -> DecodedBatch:
    """Decode a FRAME_DTYPE array. Pure and total: every row gets a kind and an outcome."""
    if frames.dtype != FRAME_DTYPE:
        frames = frames.astype(FRAME_DTYPE)
    if len(frames) == 0:
        return EMPTY_DECODED
    if len(frames) <= SCALAR_MAX:
        return decode_scalar(frames, base)
    return decode_vector(frames, base)


# -- scalar path ---------------------------------------------------------------------------
_ROW = struct.Struct("<dIBB8B")
assert _ROW.size == FRAME_DTYPE.itemsize


def _classify(can_id: int, flags: int, base: int) -> tuple[int, int]:
    """(kind, channel) exactly as the vector path decides them."""
    if flags & NOT_BOARD_FLAGS:
        return _OTHER, 0
    if can_id == SPEED_REF_ID:
        return _SPEED, 0
    offset = can_id - base
    if offset == 0:
        return _STATUS, 0
    if 1 <= offset <= 3:
        return _ADC, offset
    return _OTHER, 0


def _decode_row(row: tuple[Any, ...], base: int) -> tuple[Any, ...]:
    """One frame (unpacked FRAME_DTYPE record) -> one DECODED_DTYPE record."""
    _, can_id, dlc, flags, d0, d1, d2, d3, d4, d5, d6, d7 = row
    kind, channel = _classify(can_id, flags, base)
    if kind == _OTHER:
        outcome = _UNKNOWN_ID
    elif dlc != FRAME_DLC:
        outcome = _WRONG_DLC
    else:
        table = _CRC8_TABLE
        crc = 0xFF
        for b in (can_id & 0xFF, (can_id >> 8) & 0xFF, d0, d1, d2, d3, d4, d5, d6):
            crc = table[crc ^ b]
        outcome = _OK if crc ^ 0xFF == d7 else _CRC_MISMATCH
    code = d1 | d2 << 8 | d3 << 16
    speed = code | d4 << 24
    return (
        can_id,
        dlc,
        kind,
        channel,
        outcome,
        d0,
        code - (1 << 24) if code & 0x800000 else code,
        d4,
        d5 | d6 << 8,
        speed - (1 << 32) if speed & 0x80000000 else speed,
        d1,
        d2 | d3 << 8,
        d4 - 256 if d4 & 0x80 else d4,
        d5,
        d6,
    )


def decode_scalar(frames: np.ndarray, base: int = DEFAULT_BASE) -> DecodedBatch:
    """The Python twin of :func:`decode_vector`, for a live batch of a few frames."""
    rows = [_decode_row(row, base) for row in _ROW.iter_unpack(frames.tobytes())]
    return _columns(np.array(rows, dtype=DECODED_DTYPE))


# -- vector path ---------------------------------------------------------------------------
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


def decode_vector(frames: np.ndarray, base: int = DEFAULT_BASE) -> DecodedBatch:
    """Decode a FRAME_DTYPE array of any length with numpy."""
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
