"""What consumes pipeline output: the contract every sink (CSV, MCAP, UI snapshot) follows,
and the figures a recording sink reports."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:  # a type only: the screen process reads RecordingStatus, not the pipeline
    from bench.pipeline.steps import StepOutput


class Sink(Protocol):
    """Receives every StepOutput in order. write() must not block the caller for long:
    a sink that does I/O keeps its own bounded queue and thread and counts what it drops.
    A class that subclasses Sink has mark() and close() that do nothing unless it says
    otherwise."""

    def write(self, step: StepOutput) -> None: ...

    def mark(self, t: float, text: str) -> None:
        """An operator mark or other free-text event to record."""
        return None

    def close(self) -> None:
        return None


@dataclass(frozen=True, slots=True)
class RecordingStatus:
    """A recording's figures for a status line or the TUI. ``None``: not known for this
    sink (a figure it does not keep is left out of the display, not shown as 0)."""

    path: str
    frames: int | None = None  # frames in flushed chunks
    bytes: int | None = None  # bytes written so far
    dropped: int = 0  # frames a full queue dropped before they reached the writer
    lost: int = 0  # frames after a write error, never logged
    queue: int | None = None  # steps waiting for the writer
    error: str | None = None
    closed: bool = False
    duration_s: float | None = None  # wall time since the file was opened
    file_frames: int | None = None  # frames the file holds, counted after it failed

    def frames_text(self) -> str:
        """The frame count to show: after a failure the writer's count is not what the
        file holds (chunks written, not yet reported; a writer killed), so only a count
        read back from the file is shown."""
        if self.error:
            return "FAILED" if self.file_frames is None else f"FAILED {self.file_frames}f in file"
        return "?f" if self.frames is None else f"{self.frames}f"
