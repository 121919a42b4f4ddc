"""CRC-8/SAE-J1850 (CAN payloads) and CRC-16/CCITT-FALSE (UART packets), table driven.

Scalar forms for single frames and a numpy form that checks many CAN frames at once.
"""

from __future__ import annotations

import numpy as np


def _table8(poly: int) -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return table


def _table16(poly: int) -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
        table.append(crc)
    return table


_CRC8_TABLE = _table8(0x1D)
_CRC16_TABLE = _table16(0x1021)
CRC8_TABLE = np.array(_CRC8_TABLE, dtype=np.uint8)


def crc8_j1850(data: bytes | bytearray | memoryview) -> int:
    """CRC-8/SAE-J1850: poly 0x1D, init 0xFF, no reflection, xorout 0xFF."""
    crc = 0xFF
    table = _CRC8_TABLE
    for b in data:
        crc = table[crc ^ b]
    return crc ^ 0xFF


def crc16_ccitt_false(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no xorout."""
    crc = 0xFFFF
    table = _CRC16_TABLE
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ b]
    return crc


def frame_crc8(can_id: int, payload7: bytes | bytearray | memoryview) -> int:
    """The CRC-8 a CAN frame carries in byte 7: over ID low, ID high, payload bytes 0..6."""
    return crc8_j1850(bytes((can_id & 0xFF, (can_id >> 8) & 0xFF)) + bytes(payload7[:7]))


def frame_crc8_batch(ids: np.ndarray, data: np.ndarray) -> np.ndarray:
    """frame_crc8 over many frames: ids (N,), data (N, >=7) uint8 -> (N,) uint8."""
    ids = np.asarray(ids)
    crc = np.full(len(ids), 0xFF, dtype=np.uint8)
    crc = CRC8_TABLE[crc ^ (ids & 0xFF).astype(np.uint8)]
    crc = CRC8_TABLE[crc ^ ((ids >> 8) & 0xFF).astype(np.uint8)]
    for k in range(7):
        crc = CRC8_TABLE[crc ^ data[:, k]]
    out: np.ndarray = crc ^ np.uint8(0xFF)
    return out


def _position_tables(length: int) -> tuple[int, list[np.ndarray]]:
    """CRC-8 is affine in the message bits: crc(m) = crc(0) ^ XOR_k P_k[m_k] for messages of
    one length. Returns crc(0) and the 256-entry contribution table of each byte position."""
    values = np.arange(256, dtype=np.uint8)
    zero = crc8_j1850(bytes(length))
    tables = []
    for pos in range(length):
        crc = np.full(256, 0xFF, dtype=np.uint8)
        for k in range(length):
            crc = CRC8_TABLE[crc ^ (values if k == pos else np.uint8(0))]
        tables.append(crc ^ np.uint8(0xFF ^ zero))
    return zero, tables


def _pair_tables() -> tuple[np.ndarray, ...]:
    """65536-entry tables, one per little-endian 16-bit word of a frame (id low bytes, data
    bytes 0-1, 2-3, 4-5, 6-7): two bytes per lookup, and byte 7 (the CRC carried) folded
    in, so the XOR of the five lookups is 0 exactly where the frame's CRC is right."""
    zero, p = _position_tables(9)
    word = np.arange(1 << 16)
    lo, hi = word & 0xFF, word >> 8
    return (
        p[0][lo] ^ p[1][hi] ^ np.uint8(zero),
        p[2][lo] ^ p[3][hi],
        p[4][lo] ^ p[5][hi],
        p[6][lo] ^ p[7][hi],
        p[8][lo] ^ hi.astype(np.uint8),
    )


_PAIR_TABLES = _pair_tables()


def frame_crc8_residue(words: tuple[np.ndarray, ...]) -> np.ndarray:
    """Many frames' CRC check at two bytes per table lookup (the replay path's cost).

    ``words``: five (N,) uint16 arrays, the little-endian words (id & 0xFFFF, data[0:2],
    data[2:4], data[4:6], data[6:8]). Returns (N,) uint8, 0 where byte 7 equals
    :func:`frame_crc8` of the frame, else that CRC XOR byte 7."""
    out = _PAIR_TABLES[0].take(words[0])
    for table, w in zip(_PAIR_TABLES[1:], words[1:], strict=True):
        out ^= table.take(w)
    return out
