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
    return crc ^ np.uint8(0xFF)
