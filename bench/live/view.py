"""What a screen sees of a run and may ask of it: the :class:`Snapshot`, the history ring it
draws from, and :class:`SessionLike`, the one interface the TUI talks to.

Two sessions implement SessionLike: the in-process :class:`bench.live.session.Session` (replay
and tests) and :class:`bench.engine.client.EngineSession` (a live run in the engine process).
This module imports neither, nor the pipeline: the TUI's screen process imports it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bench.pipeline.stats import Stats
from bench.pipeline.warmup import WarmUpStatus
from bench.records.results import RESULT_DTYPE
from bench.sinks.base import RecordingStatus

HISTORY = 60_000
"""Results kept for the UI (5 min at 200 Hz, 1 min at 1 kHz)."""


class ResultRing:
    """The last ``size`` results, oldest first: the history a UI draws from (the runner's,
    and the engine's parent's, fed by the rows each snapshot brings)."""

    def __init__(self, size: int) -> None:
        self._buf = np.zeros(size, dtype=RESULT_DTYPE)
        self._pos = 0
        self._len = 0

    def __len__(self) -> int:
        return self._len

    def extend(self, rows: np.ndarray) -> None:
        size = len(self._buf)
        rows = rows[-size:]
        k = len(rows)
        first = min(k, size - self._pos)
        self._buf[self._pos : self._pos + first] = rows[:first]
        self._buf[: k - first] = rows[first:]
        self._pos = (self._pos + k) % size
        self._len = min(size, self._len + k)

    def last(self, k: int) -> np.ndarray:
        k = max(0, min(k, self._len))
        start = (self._pos - k) % len(self._buf)
        if start + k <= len(self._buf):
            return self._buf[start : start + k].copy()
        return np.concatenate([self._buf[start:], self._buf[: self._pos]])


@dataclass(frozen=True)
class ModelView:
    """The explicit model of a live run (`--lag`, bench.live.model): what its panel and the
    plot's lagged line show."""

    lag_s: float
    latest: np.void | None  # the filter's newest block (bench.records.model.MODEL_DTYPE)
    lagged: np.ndarray  # (k, 3): board time s, lagged gradient and its sigma permil, oldest first
    blocks: int  # blocks the model has run
    queued_samples: int  # waiting for the model thread
    dropped_pushes: int  # pushes a full queue dropped (the model then differs from a replay)
    dropped_samples: int
    ready: bool  # its kernels are loaded
    error: str | None = None


@dataclass
class Snapshot:
    """A consistent copy of the run's state for a UI; cheap enough to take at a few Hz."""

    wall: float
    source: str
    running: bool
    results: np.ndarray  # the last HISTORY results, oldest first
    stats: Stats
    events: list[tuple[float, int, str]]  # (receive time, EventKind, text), newest last
    board: np.void | None
    speed: np.void | None
    frames_received: int
    frames_dropped: int
    queue_depth: int
    queue_max: int
    tolerance_permil: float
    latency_ms: tuple[float, float]  # p50, p99 of frame-to-result latency over the recent window
    recording: RecordingStatus | None
    error: str | None = None
    marks: int = 0
    extra: dict[str, Any] = field(default_factory=dict)
    output_errors: list[str] = field(default_factory=list)  # failed secondary outputs (CSV)
    warmup: WarmUpStatus | None = None  # the estimator's kernel still being prepared
    model: ModelView | None = None  # the explicit model, when the run has it (--lag)


class RecorderControl(Protocol):
    """The session's recording as the screen drives it (``r``)."""

    files: list[Path]  # every file recorded in this session, in order
    last_status: RecordingStatus | None  # of the last file, once stopped

    @property
    def active(self) -> bool: ...

    @property
    def can_start(self) -> bool: ...

    def start(self) -> Path:
        """Open a new file and record into it (BenchError/OSError when it cannot)."""
        ...

    def detach(self) -> object | None:
        """Stop recording; returns a handle for :meth:`finish` (off the UI thread)."""
        ...

    def finish(self, sink: object | None) -> None: ...


class ReplayControl(Protocol):
    """A replayed log's transport keys (space, s, n, j)."""

    def toggle(self) -> bool:
        """Pause or play; True when now paused."""
        ...

    def cycle_speed(self) -> float | None:
        """The next of 1x / 10x / max (None)."""
        ...

    def step(self) -> None: ...

    def seek_failure(self) -> None: ...

    def seek_event(self, kinds: frozenset[int]) -> None:
        """Run to the next event of ``kinds`` and pause there."""
        ...

    def seek_time(self, log_t: float) -> None:
        """Run to the sample at log time ``log_t`` and pause there."""
        ...


class SessionLike(Protocol):
    """A run as the TUI sees it: snapshots to draw, and the operator's actions."""

    @property
    def mode(self) -> str:
        """ "live" or "replay"."""
        ...

    @property
    def recorder(self) -> RecorderControl: ...

    @property
    def replay(self) -> ReplayControl | None: ...

    @property
    def controllable(self) -> bool:
        """False for a session showing a fixed snapshot (no record, mark or tolerance)."""
        ...

    @property
    def sample_rate_hz(self) -> float:
        """The configured rate: how many rows a plot window needs before the board says."""
        ...

    @property
    def error(self) -> str | None:
        """Why the run failed, if it did."""
        ...

    def start(self) -> None: ...

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the run and finish every log file; safe to call twice, from any thread."""
        ...

    def snapshot(self, last: int = HISTORY) -> Snapshot: ...

    def mark(self, text: str = "operator mark") -> None: ...

    def tolerance(self) -> float: ...

    def set_tolerance(self, permil: float) -> None: ...
