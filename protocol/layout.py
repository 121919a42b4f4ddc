"""Identifiers, field constants and nominal values of the ACB-3 wire contract."""

from __future__ import annotations

from enum import IntEnum

DEFAULT_BASE = 0x100
SPEED_REF_ID = 0x180
OFFSET_STATUS = 0x00
CHANNELS = (1, 2, 3)
FRAME_DLC = 8

TICK_S = 100e-6
"""Board and odometer timestamps count 100 us ticks."""
TS_WRAP = 1 << 16
COUNTER_WRAP = 1 << 8

STATUS_OVR = 0x01
STATUS_SELFTEST = 0x02
STATUS_REF = 0x04
STATUS_CAL = 0x08
STATUS_FAULT_MASK = 0x0F
"""Any of bits 0..3 set makes the channel untrustworthy for that sample."""
STATUS_BIT_NAMES = {
    STATUS_OVR: "OVR",
    STATUS_SELFTEST: "SELFTEST",
    STATUS_REF: "REF",
    STATUS_CAL: "CAL",
}

CODE_MIN = -(1 << 23)
CODE_MAX = (1 << 23) - 1

G0 = 9.80665
NOMINAL_SCALE = 2.0 * G0 / (1 << 23)
"""m/s^2 per LSB for the nominal +/-2 g range."""
NOMINAL_ANGLES_DEG = (30.0, 0.0, -30.0)
DEFAULT_SAMPLE_RATE_HZ = 200
STATUS_RATE_HZ = 10
SPEED_REF_RATE_HZ = 50


class BoardState(IntEnum):
    BOOT = 0
    RUN = 1
    DEGRADED = 2
    FAULT = 3


class FrameKind(IntEnum):
    """What a frame is by its identifier alone."""

    OTHER = 0
    STATUS = 1
    ADC = 2
    SPEED = 3


class Outcome(IntEnum):
    """How decoding a frame or a UART packet ended. 0 is success."""

    OK = 0
    UNKNOWN_ID = 1
    WRONG_DLC = 2
    CRC_MISMATCH = 3
    COBS_ERROR = 4
    CRC16_ERROR = 5
    LENGTH_ERROR = 6


def status_names(status: int) -> list[str]:
    """Names of the set fault bits of an ADC status byte, e.g. ['OVR', 'CAL']."""
    return [name for bit, name in STATUS_BIT_NAMES.items() if status & bit]
