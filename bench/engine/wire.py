"""What the screen process and the engine process share: the signals held back while the
engine starts, and the engine's final report."""

from __future__ import annotations

import signal
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.sinks.base import RecordingStatus

SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)
"""Blocked while the parent starts the child, so none arrives before the child's handlers."""


@dataclass
class EngineReport:
    """What the parent learns when the run is over."""

    error: str | None
    frames_received: int
    frames_dropped: int
    frames_processed: int
    files: list[Path]
    last_status: RecordingStatus | None
    board: dict[str, int] | None
    stats: dict[str, Any]
    problems: list[str] = field(default_factory=list)  # thread exceptions, ERROR log records
    output: str = ""  # what the engine process wrote to stdout/stderr while the screen ran
    plan: dict[str, Any] = field(default_factory=dict)
