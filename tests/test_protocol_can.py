"""Scalar CAN codec against frames built by hand from the ICD byte tables (sections 1.1-1.4)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.can_codec import encode_adc, encode_speed, encode_status
from protocol.records import (
    AdcSample,
    BoardStatus,
    SpeedRef,
)
from tests.helpers import CrcMismatch, UnknownId, WrongDlc, decode
from tests.test_protocol_crc import frame_crc8_ref

# Section 1 identifiers, written out rather than imported from protocol.layout.
KNOWN_IDS = {0x100: "status", 0x101: 1, 0x102: 2, 0x103: 3, 0x180: "speed"}


def seal(can_id: int, body7: bytes) -> bytes:
    """A frame's 8 data bytes: the 7 payload bytes plus the reference CRC-8."""
    assert len(body7) == 7
    return body7 + bytes((frame_crc8_ref(can_id, body7),))


# --- hand-built frames -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("channel", "body", "expected"),
    [
        # counter 0x2A | code -2 = FE FF FF | status OVR|REF | timestamp 0x1234 = 34 12
        (1, "2A FE FF FF 05 34 12", AdcSample(1, 0x2A, -2, 0x05, 0x1234)),
        # most negative int24 = 00 00 80, all four fault bits, timestamp 0
        (2, "00 00 00 80 0F 00 00", AdcSample(2, 0, -(2**23), 0x0F, 0)),
        # most positive int24 = FF FF 7F, counter 255, timestamp 0xFFFF
        (3, "FF FF FF 7F 00 FF FF", AdcSample(3, 255, 2**23 - 1, 0, 0xFFFF)),
        # code 0x010203 little-endian = 03 02 01; reserved status bits are passed through
        (1, "01 03 02 01 F0 01 00", AdcSample(1, 1, 0x010203, 0xF0, 1)),
    ],
)
def test_adc_sample_from_icd_table(channel: int, body: str, expected: AdcSample) -> None:
    can_id = 0x100 + channel
    data = seal(can_id, bytes.fromhex(body))
    assert decode(can_id, data) == expected
    assert encode_adc(expected) == (can_id, data)


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        # counter 7 | RUN | 200 Hz = C8 00 | -5 degC = FB | 24.0 V = 240 = F0 | 255 errors
        ("07 01 C8 00 FB F0 FF", BoardStatus(7, 1, 200, -5, 240, 255)),
        # FAULT | 1000 Hz = E8 03 | +85 degC = 55 | 0 V | 0 errors
        ("00 03 E8 03 55 00 00", BoardStatus(0, 3, 1000, 85, 0, 0)),
        # undefined state 9 is kept, not rejected; -128 degC = 80
        ("FF 09 32 00 80 7B 01", BoardStatus(255, 9, 50, -128, 123, 1)),
    ],
)
def test_board_status_from_icd_table(body: str, expected: BoardStatus) -> None:
    data = seal(0x100, bytes.fromhex(body))
    assert decode(0x100, data) == expected
    assert encode_status(expected) == (0x100, data)


def test_board_status_supply_scale() -> None:
    assert BoardStatus(0, 1, 200, 20, 240, 0).supply_v == pytest.approx(24.0)


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        # counter 3 | -1 mm/s = FF FF FF FF | timestamp 0x1234 = 34 12
        ("03 FF FF FF FF 34 12", SpeedRef(3, -1, 0x1234)),
        # 0x12345678 mm/s = 78 56 34 12
        ("80 78 56 34 12 00 00", SpeedRef(0x80, 0x12345678, 0)),
        # int32 minimum = 00 00 00 80
        ("FF 00 00 00 80 FF FF", SpeedRef(255, -(2**31), 0xFFFF)),
    ],
)
def test_speed_ref_from_icd_table(body: str, expected: SpeedRef) -> None:
    data = seal(0x180, bytes.fromhex(body))
    assert decode(0x180, data) == expected
    assert encode_speed(expected) == (0x180, data)


def test_speed_ref_scale() -> None:
    assert SpeedRef(0, -1500, 0).speed_mps == pytest.approx(-1.5)


def test_crc_byte_is_checked() -> None:
    data = bytearray(seal(0x101, bytes.fromhex("2A FE FF FF 05 34 12")))
    data[7] ^= 0xFF
    result = decode(0x101, bytes(data))
    assert isinstance(result, CrcMismatch)
    assert result.can_id == 0x101


def test_encode_rejects_out_of_range_code() -> None:
    with pytest.raises(ValueError):
        encode_adc(AdcSample(1, 0, 2**23, 0, 0))
    with pytest.raises(ValueError):
        encode_adc(AdcSample(1, 0, -(2**23) - 1, 0, 0))
    with pytest.raises(ValueError):
        encode_adc(AdcSample(4, 0, 0, 0, 0))


# --- round trips over the full field ranges ----------------------------------------------------

u8 = st.integers(0, 255)
u16 = st.integers(0, 0xFFFF)
adc_samples = st.builds(AdcSample, st.integers(1, 3), u8, st.integers(-(2**23), 2**23 - 1), u8, u16)
board_statuses = st.builds(BoardStatus, u8, u8, u16, st.integers(-128, 127), u8, u8)
speed_refs = st.builds(SpeedRef, u8, st.integers(-(2**31), 2**31 - 1), u16)
bases = st.sampled_from([0x100, 0x200, 0x300])


@settings(max_examples=150)
@given(adc_samples, bases)
def test_adc_round_trip(sample: AdcSample, base: int) -> None:
    can_id, data = encode_adc(sample, base)
    assert can_id == base + sample.channel
    assert len(data) == 8
    assert data[7] == frame_crc8_ref(can_id, data)
    assert decode(can_id, data, base) == sample


@settings(max_examples=100)
@given(board_statuses, bases)
def test_status_round_trip(status: BoardStatus, base: int) -> None:
    can_id, data = encode_status(status, base)
    assert can_id == base
    assert data[7] == frame_crc8_ref(can_id, data)
    assert decode(can_id, data, base) == status


@settings(max_examples=100)
@given(speed_refs, bases)
def test_speed_round_trip(ref: SpeedRef, base: int) -> None:
    can_id, data = encode_speed(ref)
    assert can_id == 0x180  # SPEED_REF does not move with the board's BASE
    assert data[7] == frame_crc8_ref(can_id, data)
    assert decode(can_id, data, base) == ref


# --- bad frames ------------------------------------------------------------------------------


@settings(max_examples=300)
@given(
    st.one_of(st.sampled_from(sorted(KNOWN_IDS)), st.integers(0, 0x7FF)),
    st.binary(max_size=16),
    st.booleans(),
)
def test_arbitrary_frames_get_the_right_typed_outcome(
    can_id: int, data: bytes, fix_crc: bool
) -> None:
    if fix_crc and len(data) == 8:  # make valid frames likely, not just possible
        data = seal(can_id, data[:7])
    result = decode(can_id, data)
    if can_id not in KNOWN_IDS:
        assert isinstance(result, UnknownId)
    elif len(data) != 8:
        assert isinstance(result, WrongDlc)
    elif data[7] != frame_crc8_ref(can_id, data):
        assert isinstance(result, CrcMismatch)
    else:
        kind = KNOWN_IDS[can_id]
        if kind == "status":
            assert isinstance(result, BoardStatus)
        elif kind == "speed":
            assert isinstance(result, SpeedRef)
        else:
            assert isinstance(result, AdcSample)
            assert result.channel == kind
        return
    assert result.can_id == can_id


@settings(max_examples=200)
@given(
    st.sampled_from(sorted(KNOWN_IDS)),
    st.binary(min_size=7, max_size=7),
    st.integers(0, 63),
)
def test_any_single_bit_flip_is_a_crc_mismatch(can_id: int, body: bytes, bit: int) -> None:
    data = bytearray(seal(can_id, body))
    data[bit // 8] ^= 1 << (bit % 8)
    assert isinstance(decode(can_id, bytes(data)), CrcMismatch)


def test_configurable_base_0x200() -> None:
    body = bytes.fromhex("2A FE FF FF 05 34 12")
    assert decode(0x202, seal(0x202, body), base=0x200) == AdcSample(2, 0x2A, -2, 5, 0x1234)
    status = seal(0x200, bytes.fromhex("07 01 C8 00 FB F0 FF"))
    assert decode(0x200, status, base=0x200) == BoardStatus(7, 1, 200, -5, 240, 255)
    # the default board's IDs are foreign to a board at BASE 0x200, and vice versa
    assert isinstance(decode(0x102, seal(0x102, body), base=0x200), UnknownId)
    assert isinstance(decode(0x202, seal(0x202, body)), UnknownId)
    # a frame sealed for 0x102 but received as 0x202: the ID is inside the CRC
    assert isinstance(decode(0x202, seal(0x102, body), base=0x200), CrcMismatch)
    speed = seal(0x180, bytes.fromhex("03 FF FF FF FF 34 12"))
    assert decode(0x180, speed, base=0x200) == SpeedRef(3, -1, 0x1234)
