"""Encode of the ACB-3 CAN frames (ICD section 1), one frame at a time: what the emulator
sends and tests build frames with. Decoding has one path, :mod:`protocol.batch`, for any
batch length.
"""

from __future__ import annotations

import struct

from protocol.crc import frame_crc8
from protocol.layout import CODE_MAX, CODE_MIN, DEFAULT_BASE, SPEED_REF_ID
from protocol.records import AdcSample, BoardStatus, SpeedRef


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
