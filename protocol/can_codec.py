"""Scalar encode/decode of the ACB-3 CAN frames (ICD section 1), one frame at a time.

The bench decodes frame batches with :mod:`protocol.batch`; tests hold it to this codec.
"""

from __future__ import annotations

import struct

from protocol.crc import frame_crc8
from protocol.layout import (
    CODE_MAX,
    CODE_MIN,
    DEFAULT_BASE,
    FRAME_DLC,
    SPEED_REF_ID,
    FrameKind,
    Outcome,
    classify_id,
)
from protocol.records import (
    NOT_BOARD_FLAGS,
    AdcSample,
    BoardStatus,
    CrcMismatch,
    DecodeError,
    Record,
    SpeedRef,
    UnknownId,
    WrongDlc,
)


def _seal(can_id: int, body7: bytes) -> bytes:
    return body7 + bytes((frame_crc8(can_id, body7),))


def adc_id(channel: int, base: int = DEFAULT_BASE) -> int:
    if channel not in (1, 2, 3):
        raise ValueError(f"channel must be 1..3, not {channel}")
    return base + channel


def encode_adc(sample: AdcSample, base: int = DEFAULT_BASE) -> tuple[int, bytes]:
    """(CAN ID, 8 data bytes) of an ADC_SAMPLE frame. Raises ValueError for out-of-range fields."""
    if not CODE_MIN <= sample.code <= CODE_MAX:
        raise ValueError(f"code {sample.code} outside int24")
    can_id = adc_id(sample.channel, base)
    code = (sample.code & 0xFFFFFF).to_bytes(3, "little")
    body = struct.pack("<B3sBH", sample.counter, code, sample.status, sample.timestamp)
    return can_id, _seal(can_id, body)


def encode_status(status: BoardStatus, base: int = DEFAULT_BASE) -> tuple[int, bytes]:
    body = struct.pack(
        "<BBHbBB",
        status.counter,
        status.state,
        status.sample_rate,
        status.temperature,
        status.supply,
        status.errors,
    )
    return base, _seal(base, body)


def encode_speed(ref: SpeedRef) -> tuple[int, bytes]:
    body = struct.pack("<BiH", ref.counter, ref.speed, ref.timestamp)
    return SPEED_REF_ID, _seal(SPEED_REF_ID, body)


def decode(
    can_id: int, data: bytes, base: int = DEFAULT_BASE, flags: int = 0
) -> Record | DecodeError:
    """Decode one frame. Never raises for bad bytes: failures come back as DecodeError.

    ``flags`` (protocol.records.FLAG_*): extended, remote and error frames are never the board's.
    """
    kind, channel = classify_id(can_id, base)
    if kind is FrameKind.OTHER or flags & NOT_BOARD_FLAGS:
        return UnknownId(Outcome.UNKNOWN_ID, can_id, f"id 0x{can_id:03X}")
    if len(data) != FRAME_DLC:
        return WrongDlc(Outcome.WRONG_DLC, can_id, f"dlc {len(data)}, expected {FRAME_DLC}")
    expected = frame_crc8(can_id, data[:7])
    if data[7] != expected:
        return CrcMismatch(
            Outcome.CRC_MISMATCH, can_id, f"crc 0x{data[7]:02X}, expected 0x{expected:02X}"
        )
    if kind is FrameKind.ADC:
        code = int.from_bytes(data[1:4], "little", signed=True)
        return AdcSample(channel, data[0], code, data[4], data[5] | (data[6] << 8))
    if kind is FrameKind.STATUS:
        counter, state, rate, temp, supply, errors = struct.unpack_from("<BBHbBB", data)
        return BoardStatus(counter, state, rate, temp, supply, errors)
    counter, speed, ts = struct.unpack_from("<BiH", data)
    return SpeedRef(counter, speed, ts)
