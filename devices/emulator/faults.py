"""Fault injection: pure functions that bend signals, codes, frame sequences and UART packets.

Three layers, applied in this order (layer 1 by :mod:`devices.emulator.engine`, 2 and 3 by
:mod:`devices.emulator.simulation` and :mod:`devices.emulator.stream`):

1. signal faults inside the board (``drift``, ``spike``, ``saturate`` on the sensor value;
   ``stuck`` on the ADC code; ``status`` bits) -- seen on CAN and UART alike;
2. source faults on whole frames (``dropout``, ``counter_jump``, ``crc``) -- the board (or
   the odometer) sends them that way, so they too reach both links;
3. link faults: ``duplicate`` (before bus scheduling: the copy takes bus time), ``loss`` and
   ``reorder`` (after it, at the receiving adapter) on CAN only; ``noise`` and ``truncation``
   on the UART byte stream only.

Every random choice comes from a generator seeded by (scenario seed, layer, fault index), so
adding a fault never changes the noise or another fault's choices.
"""

from __future__ import annotations

import numpy as np
from cobs import cobs

from devices.emulator.scenario import Fault
from protocol.crc import crc16_ccitt_false
from protocol.layout import FrameKind

LAYER_NOISE = 1
LAYER_FAULT = 2
LAYER_ODOMETER = 3
LAYER_UART = 4
LAYER_VIBRATION = 5
LAYER_WHEEL = 6
LAYER_BODY_MODES = 7  # issue 25: the car body's bounce, pitch and bending modes
LAYER_TRACK = 8  # issue 25: the line's joints (seeded by track_seed, not the run's seed)
LAYER_BODY_PITCH = 11  # issue 25's physics: 11.. (other helpers' streams take 7..10)
LAYER_STANDSTILL = 12
LAYER_BIAS_WALK = 13  # index: the channel (1..3)


def rng_for(seed: int, layer: int, index: int = 0) -> np.random.Generator:
    """An independent generator per (layer, index): same seed -> same draws, bit for bit."""
    return np.random.default_rng([seed, layer, index])


def to_us(seconds: float) -> int:
    return round(seconds * 1e6)


def in_window(times_us: np.ndarray, fault: Fault) -> np.ndarray:
    """Which instants fall in the fault's half-open window [start_s, end_s)."""
    return (times_us >= to_us(fault.start_s)) & (times_us < to_us(fault.end_s))


def target_channels(fault: Fault) -> tuple[int, ...]:
    """ADC channel numbers (1..3) a fault acts on."""
    if isinstance(fault.target, int):
        return (fault.target,)
    return (1, 2, 3) if fault.target in ("adc", "bus") else ()


def frame_targets(fault: Fault, kind: np.ndarray, channel: np.ndarray) -> np.ndarray:
    """Which frames of a sequence a frame-level fault's target names."""
    t = fault.target
    hit: np.ndarray
    if isinstance(t, int):
        hit = (kind == FrameKind.ADC) & (channel == t)
    elif t == "adc":
        hit = kind == FrameKind.ADC
    elif t == "status":
        hit = kind == FrameKind.STATUS
    elif t == "speed":
        hit = kind == FrameKind.SPEED
    else:  # "bus"
        hit = np.ones(len(kind), dtype=bool)
    return hit


def pick(mask: np.ndarray, probability: float, rng: np.random.Generator) -> np.ndarray:
    """Subset of a mask, each member kept with the given probability (1.0: all of them)."""
    if probability >= 1.0:
        return mask.copy()
    out = np.zeros_like(mask)
    idx = np.flatnonzero(mask)
    out[idx[rng.random(len(idx)) < probability]] = True
    return out


# ------------------------------------------------------------------ layer 1: inside the board


def apply_value_fault(values: np.ndarray, fault: Fault, t_us: np.ndarray) -> np.ndarray:
    """drift or saturate on the sensor values (3, n) in place; returns the samples hit.

    (spike and stuck carry state across blocks: :mod:`devices.emulator.engine` does them.)"""
    win = in_window(t_us, fault)
    p = fault.params
    hit = np.zeros(len(t_us), dtype=bool)
    for ch in target_channels(fault):
        row = values[ch - 1]
        if fault.kind == "drift":
            dt = (t_us[win] - to_us(fault.start_s)) / 1e6
            row[win] += p["offset_mps2"] + p["rate_mps2_per_s"] * dt
        else:  # saturate
            row[win] = p["value_mps2"]
        hit |= win
    return np.flatnonzero(hit)


def apply_status_bits(status: np.ndarray, fault: Fault, t_us: np.ndarray) -> np.ndarray:
    """OR the fault's bits into the status byte of the target channels; returns samples hit."""
    idx = np.flatnonzero(in_window(t_us, fault))
    for ch in target_channels(fault):
        status[ch - 1, idx] |= np.uint8(fault.params["bits"])
    return idx


# --------------------------------------------------------------- layer 2/3: frame sequences


def duplicate_rows(n: int, dup: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row order with each marked row repeated right after itself; also the is-copy flags."""
    order = np.repeat(np.arange(n), 1 + dup.astype(np.int64))
    is_copy = np.zeros(len(order), dtype=bool)
    is_copy[1:] = order[1:] == order[:-1]
    return order, is_copy


def serialise(queue_us: np.ndarray, gap_us: int) -> np.ndarray:
    """Bus send times: each frame goes when queued, but not before the previous one is done.

    send[k] = max(queue[k], send[k-1] + gap), solved without a loop: subtracting k*gap turns
    the recurrence into a running maximum.
    """
    k = np.arange(len(queue_us), dtype=np.int64) * gap_us
    return np.maximum.accumulate(queue_us - k) + k


def flip_bits(data: np.ndarray, rows: np.ndarray, rng: np.random.Generator) -> None:
    """Flip one random bit of the 8 payload bytes of each row (in place).

    CRC-8/SAE-J1850 detects every single-bit error, so each of these frames fails its CRC.
    """
    bit = rng.integers(0, 64, size=len(rows))
    data[rows, bit // 8] ^= (1 << (bit % 8)).astype(np.uint8)


# ---------------------------------------------------------------------- layer 3: UART bytes


def packet_valid(body: bytes) -> bool:
    """Would a receiver accept this packet (the bytes before its 0x00)? ICD section 2."""
    try:
        out: bytes = cobs.decode(body)
    except cobs.DecodeError:
        return False
    if len(out) < 5 or len(out) != 3 + out[2] + 2:
        return False
    return crc16_ccitt_false(out[:-2]) == out[-2] | (out[-1] << 8)


def inject_noise(body: bytes, burst: int, rng: np.random.Generator) -> bytes:
    """Line noise: ``burst`` non-zero garbage bytes inserted somewhere inside one packet.

    Non-zero so the garbage cannot end the packet early: one burst breaks exactly one packet.
    """
    for _ in range(16):
        at = int(rng.integers(0, len(body) + 1))
        junk = rng.integers(1, 256, size=burst, dtype=np.uint8).tobytes()
        out = body[:at] + junk + body[at:]
        if not packet_valid(out):
            return out
    return body[:1]  # astronomically unlikely; a one-byte packet is always invalid


def truncate(body: bytes, rng: np.random.Generator) -> bytes:
    """Bytes lost before the delimiter: keep a random non-empty proper prefix of the packet."""
    for _ in range(16):
        out = body[: int(rng.integers(1, len(body)))]
        if not packet_valid(out):
            return out
    return body[:1]
