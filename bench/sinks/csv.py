"""The results as CSV (``--csv``) for any run, live or replay."""

from __future__ import annotations

from bench.pipeline.steps import StepOutput


class CsvSink:
    """Adapts bench.records.results.CsvWriter to the Sink contract."""

    def __init__(self, path: str) -> None:
        from bench.records.results import CsvWriter

        self._writer = CsvWriter(path)

    def write(self, step: StepOutput) -> None:
        self._writer.write(step.results)

    def mark(self, t: float, text: str) -> None:
        pass

    def close(self) -> None:
        self._writer.close()

    @property
    def rows(self) -> int:
        return self._writer.rows
