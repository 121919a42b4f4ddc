"""What consumes pipeline output: the contract every sink (CSV, MCAP, UI snapshot) follows."""

from __future__ import annotations

from typing import Protocol

from bench.pipeline.steps import StepOutput


class Sink(Protocol):
    """Receives every StepOutput in order. write() must not block the caller for long:
    a sink that does I/O keeps its own bounded queue and thread and counts what it drops."""

    def write(self, step: StepOutput) -> None: ...

    def mark(self, t: float, text: str) -> None:
        """An operator mark or other free-text event to record."""
        ...

    def close(self) -> None: ...
