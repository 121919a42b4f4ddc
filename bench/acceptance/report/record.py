"""record.json: everything about the run that a later reader needs, in one versioned file."""

from __future__ import annotations

import hashlib
import platform
import socket
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bench import __version__
from bench.acceptance.expectation import expectation_text, plan_line, status_of
from bench.acceptance.model import Measurement
from bench.acceptance.outcome import RunOutcome
from bench.acceptance.report.measured import reading_extra
from bench.acceptance.report.text import counts

RECORD_FORMAT = "acb3-bench-acceptance-record/1"


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _measurement(m: Measurement, plan: Any) -> dict[str, Any]:
    """A measurement as recorded: its own fields, how it stands against the plan's
    expectation, the requirements it verifies and a step check's reading."""
    return {
        **m.as_dict(),
        "status": status_of(m),
        "expectation": expectation_text(m),
        "requirements": list(plan.requirement_ids(m.name)),
        **reading_extra(m),
    }


def build_record(outcome: RunOutcome, files: dict[str, Any]) -> dict[str, Any]:
    plan = outcome.plan
    run = outcome.run
    run_info: dict[str, Any] = {
        "mode": outcome.mode,
        "source": outcome.source,
        "link": plan.link if run is None else run.link,
        "started_utc": outcome.started_utc,
        "finished_utc": outcome.finished_utc,
        "wall_s": round(outcome.wall_s, 3),
    }
    if run is not None:
        run_info.update(
            sample_rate_hz=run.rate_hz,
            samples=len(run.results),
            sample_span=run.n_samples,
            frames={
                "sent": run.frames_sent,
                "received": run.frames_received,
                "logged": run.frames_logged,
                "dropped": run.frames_dropped,
            },
            latency_ms=None if run.latency_ms is None else list(run.latency_ms),
            steps=[
                {
                    "step": s.index,
                    "prompt": s.prompt,
                    "expected_permil": s.expected_permil,
                    "answer": s.answer,
                    "note": s.note,
                    "confirmed_at_s": s.start_s,
                    "window_s": [s.from_s, s.to_s],
                }
                for s in run.steps
            ],
            faults=[
                {
                    "index": f.index,
                    "label": f.label,
                    "kind": f.kind,
                    "channels": list(f.channels),
                    "start_s": f.start_s,
                    "end_s": f.end_s,
                    "onset_sample": f.onset_k,
                    "affected": f.affected,
                }
                for f in run.faults
            ],
        )
    run_info.update(outcome.info)
    return {
        "format": RECORD_FORMAT,
        "result": outcome.result,
        "summary": plan_line(plan.name, plan.expect, outcome.measurements, outcome.result),
        "verdict": outcome.verdict,
        "exit_code": outcome.exit_code,
        "expected_verdict": plan.expect,
        "error": outcome.error,
        **outcome.context.record(),
        "counts": counts(outcome.measurements),
        "measurements": [_measurement(m, plan) for m in outcome.measurements],
        "plan": {
            "name": plan.name,
            "title": plan.title,
            "path": None if plan.path is None else str(plan.path),
            "sha256": hashlib.sha256(plan.text.encode()).hexdigest(),
            "text": plan.text,
        },
        "bench": {
            "version": __version__,
            "python": sys.version.split()[0],
            "numpy": np.__version__,
            "platform": platform.platform(),
            "host": socket.gethostname(),
        },
        "run": run_info,
        "config": {
            "source": outcome.config.source,
            "origin": outcome.config.origin,
            "described": outcome.config.describe(),
            "toml": outcome.config.to_toml(),
            "values": outcome.config.as_dict(),
        },
        "scenario": None
        if plan.scenario is None
        else {"ref": plan.scenario_ref, "toml": plan.scenario_toml()},
        "files": files,
    }
