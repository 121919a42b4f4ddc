"""Helpers for the TUI tests: hand-made ACB-3 streams (independent of the emulator), a list
source that plays them into a LiveRunner, and plain-text access to what the screen shows.

No tests here; the module is named test_tui_* so it belongs with the TUI tests it serves.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator, Sequence

import numpy as np

from bench.config import Config
from bench.live.runner import LiveRunner
from bench.live.view import Snapshot
from bench.pipeline.warmup import PendingEstimator
from bench.sinks.base import RecordingStatus
from devices.base import FileSource, LiveSource, SourceBatch
from protocol.can_codec import encode_adc, encode_speed, encode_status
from protocol.frames import FRAME_DTYPE
from protocol.layout import G0, NOMINAL_ANGLES_DEG, NOMINAL_SCALE, STATUS_RATE_HZ
from protocol.records import AdcSample, BoardStatus, SpeedRef

T0 = 1_700_000_000.0
"""Receive time of the first frame (2023-11-14 22:13:20 UTC): fixed, so screens are too."""


def codes_for(
    gradient_permil: float,
    accel_mps2: float = 0.0,
    perturb_mps2: Sequence[float] = (0.0, 0.0, 0.0),
) -> list[int]:
    """Raw codes of the three channels for a gradient (ICD section 3: a_i = a cos(theta_i) +
    g sin(alpha + theta_i)), nominal angles and scale, plus an error on chosen channels."""
    alpha = math.atan(gradient_permil / 1000.0)
    out = []
    for k, deg in enumerate(NOMINAL_ANGLES_DEG):
        th = math.radians(deg)
        a = accel_mps2 * math.cos(th) + G0 * math.sin(alpha + th) + perturb_mps2[k]
        out.append(round(a / NOMINAL_SCALE))
    return out


def make_frames(
    n_samples: int,
    *,
    rate: int = 200,
    gradient_permil: float = 20.0,
    perturb_mps2: Sequence[float] = (0.0, 0.0, 0.0),
    status: Sequence[int] = (0, 0, 0),
    speed_mm_s: int | None = 10_000,
    t0: float = T0,
    board_state: int = 1,
    start: int = 0,
) -> np.ndarray:
    """A clean stream: instants start..start+n_samples-1 (ch1..ch3), BOARD_STATUS at 10 Hz,
    SPEED_REF at 50 Hz. ``start`` continues an earlier stream (counters, board time, t)."""
    codes = codes_for(gradient_permil, 0.0, perturb_mps2)
    rows: list[tuple[float, int, bytes]] = []
    period_ticks = 10_000 // rate
    status_every = max(1, rate // STATUS_RATE_HZ)
    speed_every = max(1, rate // 50)
    for k in range(start, start + n_samples):
        t = t0 + k / rate
        if k % status_every == 0:
            cid, data = encode_status(
                BoardStatus((k // status_every) % 256, board_state, rate, 31, 241, 0)
            )
            rows.append((t, cid, data))
        for ch in (1, 2, 3):
            cid, data = encode_adc(
                AdcSample(ch, k % 256, codes[ch - 1], status[ch - 1], (k * period_ticks) % 65536)
            )
            rows.append((t + ch * 1e-4, cid, data))
        if speed_mm_s is not None and k % speed_every == 0:
            cid, data = encode_speed(
                SpeedRef((k // speed_every) % 256, speed_mm_s, (k * period_ticks + 7) % 65536)
            )
            rows.append((t + 4e-4, cid, data))
    out = np.zeros(len(rows), dtype=FRAME_DTYPE)
    out["t"] = [r[0] for r in rows]
    out["id"] = [r[1] for r in rows]
    out["dlc"] = 8
    out["data"] = np.frombuffer(b"".join(r[2] for r in rows), dtype=np.uint8).reshape(-1, 8)
    return out


class ListSource(LiveSource):
    """Hands out a fixed frame array in chunks, then nothing (like a board that went quiet)."""

    description = "test frames"

    def __init__(self, frames: np.ndarray, chunk: int = 64, delay_s: float = 0.0) -> None:
        self.frames = frames
        self.chunk = chunk
        self.delay_s = delay_s
        self.pos = 0
        self.closed = False
        self._lock = threading.Lock()

    def feed(self, frames: np.ndarray) -> None:
        with self._lock:
            self.frames = np.concatenate([self.frames, frames])

    def read(self, timeout: float) -> SourceBatch:
        with self._lock:
            if self.closed or self.pos >= len(self.frames):
                batch = None
            else:
                batch = self.frames[self.pos : self.pos + self.chunk].copy()
                self.pos += len(batch)
        if batch is None:
            time.sleep(min(timeout, 0.005))
            return SourceBatch()
        if self.delay_s:
            time.sleep(self.delay_s)
        return SourceBatch(batch)

    def close(self) -> None:
        self.closed = True


class ListFile(FileSource):
    """A 'log file' holding a frame array, for replay tests."""

    description = "test log"

    def __init__(self, frames: np.ndarray) -> None:
        self.frames = frames
        self.pos = 0

    def batches(self, max_frames: int = 65536) -> Iterator[SourceBatch]:
        for i in range(0, len(self.frames), max_frames):
            self.pos = min(len(self.frames), i + max_frames)
            yield SourceBatch(self.frames[i : i + max_frames].copy())

    def size_bytes(self) -> int:
        return len(self.frames)

    def position(self) -> int:
        return self.pos


class FakeSink:
    """Records what an MCAP sink would be asked to do."""

    def __init__(self, path: str = "logs/fake.mcap") -> None:
        self.path = path
        self.frames = 0
        self.marks: list[str] = []
        self.closed = False
        self.writes_after_close = 0

    def write(self, step: object) -> None:
        if self.closed:
            self.writes_after_close += 1
        self.frames += len(step.frames)  # type: ignore[attr-defined]

    def mark(self, t: float, text: str) -> None:
        self.marks.append(text)

    def close(self) -> None:
        self.closed = True

    def status(self) -> RecordingStatus:
        return RecordingStatus(path=self.path, frames=self.frames, bytes=1000 + self.frames * 20)


def settled_snapshot(
    frames: np.ndarray, config: Config | None = None, *, estimator: bool = True
) -> Snapshot:
    """Run frames through a real LiveRunner to the end and freeze what depends on the clock."""
    runner = LiveRunner(ListSource(frames, chunk=256), config or Config())
    if not estimator:
        runner.pipeline.estimator = PendingEstimator()
    runner.start()
    deadline = time.monotonic() + 10
    while runner.pipeline.seq < len(frames) and time.monotonic() < deadline:
        time.sleep(0.01)
    runner.stop()
    snap = runner.snapshot()
    snap.wall = T0 + 3600.0
    snap.latency_ms = (0.42, 1.37)
    snap.queue_depth = 0
    snap.running = True
    return snap


def screen_text(app: object) -> str:
    """The screen as plain text, line by line (what a person would read)."""
    strips = app.screen._compositor.render_strips()  # type: ignore[attr-defined]
    return "\n".join(s.text for s in strips)
