"""Frames as received, UART link errors, and one record type per message (what the encoders
take; decoding gives columns, :mod:`protocol.batch`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from protocol.layout import Outcome


class RawFrame(NamedTuple):
    """A CAN frame as received, before decoding. Every frame source yields these.

    ``t`` is the receive time in seconds (POSIX time for live sources, the logged
    time for files, NaN where the medium carries none, e.g. a raw UART capture).
    """

    t: float
    can_id: int
    data: bytes
    flags: int = 0  # FLAG_* bits below


FLAG_EXTENDED = 0x01
FLAG_REMOTE = 0x02
FLAG_ERROR = 0x04
FLAG_FD = 0x08
FLAG_UART = 0x10
"""The frame arrived as a UART packet rather than on CAN."""
NOT_BOARD_FLAGS = FLAG_EXTENDED | FLAG_REMOTE | FLAG_ERROR
"""Frames with any of these flags cannot come from the board (11-bit data frames only)."""


class LinkError(NamedTuple):
    """A UART packet that could not be turned into a frame; ``raw`` is its bytes as received."""

    t: float
    outcome: Outcome  # COBS_ERROR, CRC16_ERROR or LENGTH_ERROR
    raw: bytes
    detail: str = ""


@dataclass(frozen=True, slots=True)
class AdcSample:
    channel: int  # 1..3
    counter: int  # 0..255
    code: int  # int24
    status: int  # bits 0..3 are faults
    timestamp: int  # 100 us ticks, 0..65535


@dataclass(frozen=True, slots=True)
class BoardStatus:
    counter: int
    state: int  # BoardState value (kept as int: the board may send an undefined one)
    sample_rate: int  # Hz
    temperature: int  # deg C
    supply: int  # 0.1 V per bit
    errors: int

    @property
    def supply_v(self) -> float:
        return self.supply * 0.1


@dataclass(frozen=True, slots=True)
class SpeedRef:
    counter: int
    speed: int  # mm/s, signed
    timestamp: int  # odometer ticks

    @property
    def speed_mps(self) -> float:
        return self.speed / 1000.0


Record = AdcSample | BoardStatus | SpeedRef
