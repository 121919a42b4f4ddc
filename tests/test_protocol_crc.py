"""CRC-8/SAE-J1850 and CRC-16/CCITT-FALSE against the ICD check values and a bitwise reference.

The reference functions here follow the textbook shift-register definition (no tables)
so that they share nothing with protocol.crc; other protocol tests import them.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from protocol.crc import (
    crc8_j1850,
    crc16_ccitt_false,
    frame_crc8,
    frame_crc8_batch,
    frame_crc8_residue,
)

CHECK_INPUT = b"123456789"


def crc8_ref(data: bytes) -> int:
    """CRC-8/SAE-J1850 bit by bit: poly 0x1D, init 0xFF, MSB first, xorout 0xFF."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def crc16_ref(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit: poly 0x1021, init 0xFFFF, MSB first, no xorout."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def frame_crc8_ref(can_id: int, payload: bytes) -> int:
    """ICD 1.4: over ID & 0xFF, ID >> 8, then payload bytes 0..6."""
    return crc8_ref(bytes((can_id & 0xFF, (can_id >> 8) & 0xFF)) + payload[:7])


def test_check_values_from_icd() -> None:
    assert crc8_j1850(CHECK_INPUT) == 0x4B
    assert crc16_ccitt_false(CHECK_INPUT) == 0x29B1
    # the references must reproduce the published check values too, or they prove nothing
    assert crc8_ref(CHECK_INPUT) == 0x4B
    assert crc16_ref(CHECK_INPUT) == 0x29B1


def test_empty_input_is_init_xor_out() -> None:
    assert crc8_j1850(b"") == 0xFF ^ 0xFF
    assert crc16_ccitt_false(b"") == 0xFFFF


def test_accepts_bytearray_and_memoryview() -> None:
    assert crc8_j1850(bytearray(CHECK_INPUT)) == 0x4B
    assert crc16_ccitt_false(memoryview(CHECK_INPUT)) == 0x29B1


@settings(max_examples=200)
@given(st.binary(max_size=64))
def test_crc8_matches_bitwise_reference(data: bytes) -> None:
    assert crc8_j1850(data) == crc8_ref(data)


@settings(max_examples=200)
@given(st.binary(max_size=64))
def test_crc16_matches_bitwise_reference(data: bytes) -> None:
    assert crc16_ccitt_false(data) == crc16_ref(data)


@settings(max_examples=200)
@given(st.integers(0, 0x7FF), st.binary(min_size=7, max_size=8))
def test_frame_crc8_covers_id_then_seven_bytes(can_id: int, payload: bytes) -> None:
    assert frame_crc8(can_id, payload) == frame_crc8_ref(can_id, payload)


@settings(max_examples=100)
@given(
    hnp.arrays(np.uint32, st.integers(0, 40), elements=st.integers(0, 0xFFFF)).flatmap(
        lambda ids: st.tuples(
            st.just(ids), hnp.arrays(np.uint8, (len(ids), 8), elements=st.integers(0, 255))
        )
    )
)
def test_frame_crc8_batch_equals_scalar(arrays: tuple[np.ndarray, np.ndarray]) -> None:
    ids, data = arrays
    got = frame_crc8_batch(ids, data)
    assert got.dtype == np.uint8
    assert got.shape == ids.shape
    assert got.tolist() == [
        frame_crc8_ref(int(i), bytes(row)) for i, row in zip(ids, data, strict=True)
    ]


@settings(max_examples=100, deadline=None)
@given(
    st.integers(0, 40).flatmap(
        lambda n: st.tuples(
            st.lists(st.integers(0, 2**32 - 1), min_size=n, max_size=n),
            hnp.arrays(np.uint8, (n, 8)),
            st.lists(st.booleans(), min_size=n, max_size=n),
        )
    )
)
def test_pair_table_residue_is_zero_exactly_where_the_crc_is_right(case) -> None:
    """The decoder's CRC check (two bytes per table lookup) against the bitwise CRC-8."""
    ids, data, right = case
    for i, fix in enumerate(right):  # about half the frames carry their right CRC
        if fix:
            data[i, 7] = frame_crc8_ref(ids[i], bytes(data[i, :7]))
    id16 = np.array([i & 0xFFFF for i in ids], dtype=np.uint16)
    pairs = np.ascontiguousarray(data).view("<u2").reshape(len(ids), 4)
    residue = frame_crc8_residue((id16, *(pairs[:, k] for k in range(4))))
    expected = [
        frame_crc8_ref(i, bytes(row[:7])) ^ int(row[7]) for i, row in zip(ids, data, strict=True)
    ]
    assert residue.dtype == np.uint8
    assert residue.tolist() == expected
