"""A finished acceptance run as the reports and the command see it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.acceptance import expectation
from bench.acceptance.model import Measurement, RunData
from bench.acceptance.plan import Plan
from bench.acceptance.signoff import RunContext
from bench.config import Config


@dataclass
class RunOutcome:
    """A finished acceptance run."""

    plan: Plan
    verdict: str
    measurements: list[Measurement]
    run: RunData | None
    config: Config
    mode: str
    source: str
    started_utc: str
    finished_utc: str
    wall_s: float
    out_dir: Path
    error: str | None = None
    files: dict[str, Path] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)  # sim summary, stats, fault record
    context: RunContext = field(default_factory=RunContext)  # unit, station, operator, board

    @property
    def result(self) -> str:
        """pass / fail / error: whether the run behaved as the plan designed it
        (:mod:`bench.acceptance.expectation`); ``verdict`` is what the device did."""
        return expectation.result(self.measurements, self.error)

    @property
    def exit_code(self) -> int:
        return expectation.EXIT_CODES[self.result]
