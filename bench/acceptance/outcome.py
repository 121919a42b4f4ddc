"""A finished acceptance run as the reports and the command see it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.acceptance.model import EXIT_CODES, Measurement, RunData
from bench.acceptance.plan import Plan
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

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.verdict]
