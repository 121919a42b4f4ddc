"""The board and the odometer as frame producers: field values -> wire frames (ICD section 1).

Pure functions. ADC frames are packed column-wise with numpy (1.8 M frames in well under a
second) using the same byte layout as :func:`protocol.can_codec.encode_adc` and the
protocol's own batch CRC; the tests hold the two encoders equal. The few BOARD_STATUS and
SPEED_REF frames go through :mod:`protocol.can_codec` directly.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from protocol.can_codec import encode_speed, encode_status
from protocol.crc import frame_crc8_batch
from protocol.layout import SPEED_REF_ID, FrameKind
from protocol.records import BoardStatus, SpeedRef


@dataclass(slots=True)
class FrameSet:
    """Frames of one stream (or a merged sequence) with what the emulator knows about each."""

    queue_us: np.ndarray  # int64: when the sender hands the frame to the bus (relative)
    when_us: np.ndarray  # int64: the instant the frame describes (fault windows use this)
    can_id: np.ndarray  # uint32
    data: np.ndarray  # (N, 8) uint8
    kind: np.ndarray  # uint8 FrameKind
    channel: np.ndarray  # uint8 1..3 for ADC, else 0
    seq: np.ndarray  # int64 index within the frame's own stream (sample index for ADC)

    def __len__(self) -> int:
        return len(self.can_id)

    def take(self, rows: np.ndarray) -> FrameSet:
        return FrameSet(
            self.queue_us[rows],
            self.when_us[rows],
            self.can_id[rows],
            self.data[rows],
            self.kind[rows],
            self.channel[rows],
            self.seq[rows],
        )

    @staticmethod
    def concat(parts: list[FrameSet]) -> FrameSet:
        return FrameSet(
            *(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(FrameSet))
        )


def adc_frames(
    base_id: int,
    sample_us: np.ndarray,
    latency_us: int,
    counters: np.ndarray,
    codes: np.ndarray,
    status: np.ndarray,
    timestamps: np.ndarray,
) -> FrameSet:
    """ADC_SAMPLE frames, three per sampling instant back to back (ch1, ch2, ch3).

    counters, codes, status: (3, n) per channel; timestamps: (n,) board ticks.
    """
    n = len(sample_us)
    data = np.zeros((n, 3, 8), dtype=np.uint8)
    data[:, :, 0] = (counters.T & 0xFF).astype(np.uint8)
    c = codes.T.astype(np.int64) & 0xFFFFFF
    data[:, :, 1] = c & 0xFF
    data[:, :, 2] = (c >> 8) & 0xFF
    data[:, :, 3] = (c >> 16) & 0xFF
    data[:, :, 4] = status.T
    ts = (timestamps.astype(np.int64) & 0xFFFF)[:, None]
    data[:, :, 5] = ts & 0xFF
    data[:, :, 6] = ts >> 8
    flat = data.reshape(-1, 8)
    ids = np.tile(np.array([base_id + 1, base_id + 2, base_id + 3], dtype=np.uint32), n)
    flat[:, 7] = frame_crc8_batch(ids, flat)
    when = np.repeat(sample_us, 3)
    return FrameSet(
        queue_us=when + latency_us,
        when_us=when,
        can_id=ids,
        data=flat,
        kind=np.full(3 * n, FrameKind.ADC, dtype=np.uint8),
        channel=np.tile(np.array([1, 2, 3], dtype=np.uint8), n),
        seq=np.repeat(np.arange(n, dtype=np.int64), 3),
    )


def status_frames(
    base_id: int,
    when_us: np.ndarray,
    counters: np.ndarray,
    states: np.ndarray,
    sample_rate_hz: int,
    temperature_c: np.ndarray,
    supply_v: float,
    errors: np.ndarray,
) -> FrameSet:
    """BOARD_STATUS frames, encoded one by one with protocol.can_codec (10 per second);
    ``temperature_c`` per frame (whole degrees)."""
    supply = min(max(round(supply_v * 10), 0), 255)
    rows = []
    for k in range(len(when_us)):
        _, body = encode_status(
            BoardStatus(
                int(counters[k]) & 0xFF,
                int(states[k]),
                sample_rate_hz,
                int(temperature_c[k]),
                supply,
                min(int(errors[k]), 255),
            ),
            base_id,
        )
        rows.append(body)
    return _single_stream(when_us, base_id, rows, FrameKind.STATUS)


def speed_frames(
    when_us: np.ndarray, counters: np.ndarray, speed_mm_s: np.ndarray, ticks: np.ndarray
) -> FrameSet:
    """SPEED_REF frames from the odometer unit, encoded with protocol.can_codec."""
    rows = []
    for k in range(len(when_us)):
        _, body = encode_speed(
            SpeedRef(int(counters[k]) & 0xFF, int(speed_mm_s[k]), int(ticks[k]) & 0xFFFF)
        )
        rows.append(body)
    return _single_stream(when_us, SPEED_REF_ID, rows, FrameKind.SPEED)


def _single_stream(when_us: np.ndarray, can_id: int, rows: list[bytes], kind: int) -> FrameSet:
    n = len(rows)
    data = np.frombuffer(b"".join(rows), dtype=np.uint8).reshape(n, 8).copy()
    return FrameSet(
        queue_us=when_us.astype(np.int64),
        when_us=when_us.astype(np.int64),
        can_id=np.full(n, can_id, dtype=np.uint32),
        data=data,
        kind=np.full(n, kind, dtype=np.uint8),
        channel=np.zeros(n, dtype=np.uint8),
        seq=np.arange(n, dtype=np.int64),
    )


_PRIORITY = {FrameKind.STATUS: 0, FrameKind.ADC: 1, FrameKind.SPEED: 2}


def merge(parts: list[FrameSet]) -> FrameSet:
    """One sequence in bus order: by queue time; at equal times BOARD_STATUS (lowest ID) wins
    arbitration over the ADC triple, which wins over SPEED_REF; a triple stays ch1, ch2, ch3."""
    allf = FrameSet.concat(parts)
    prio = np.zeros(len(allf), dtype=np.int64)
    for kind, p in _PRIORITY.items():
        prio[allf.kind == kind] = p
    order = np.argsort(allf.queue_us * 4 + prio, kind="stable")
    return allf.take(order)
