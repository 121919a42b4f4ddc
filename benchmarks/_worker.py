"""Run one measurement in this process and print its figures as JSON (used by __main__).

    python -m benchmarks._worker NAME '{"kwarg": value}'

Progress goes to stderr; the last stdout line is ``FIGURES <json list>``.
"""

from __future__ import annotations

import importlib
import json
import sys
import traceback
from typing import Any

from benchmarks.common import Figure

MARKER = "FIGURES "
PARTIAL = "FIGURE "


class _Emitting(list):
    """A list of figures that prints each one as it is added, so that a measurement that
    runs out of time still reports what it had (the parent reads them from the output)."""

    def append(self, fig: Figure) -> None:
        super().append(fig)
        print(PARTIAL + json.dumps(fig.as_dict()), flush=True)


def _log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


MEASUREMENTS = {  # name: module, function, what it is handed (out: figures as they come)
    "replay": ("replay", "measure", "out"),
    "fusion": ("fusion", "measure", ""),
    "live_rate": ("live", "measure_rate", "log"),
    "latency": ("live", "measure_latency", ""),
    "replay_process": ("replay_process", "measure", ""),
    "replay_memory": ("outputs", "measure_memory", "out"),
    "fleet": ("outputs", "measure_fleet", "out"),
    "accuracy": ("accuracy", "measure", "log"),
    "random": ("random_accuracy", "measure", "log"),
    "calibration": ("calibration", "measure", "log"),
    "rec_toggle": ("rec_toggle", "measure", ""),
}


def run(name: str, kwargs: dict[str, Any]) -> list[Figure]:
    if name not in MEASUREMENTS:
        raise SystemExit(f"unknown measurement {name!r}")
    module, function, given = MEASUREMENTS[name]
    measure = getattr(importlib.import_module(f"benchmarks.{module}"), function)
    if given == "out":
        kwargs = {**kwargs, "out": _Emitting()}
    elif given == "log":
        kwargs = {**kwargs, "log": _log}
    figures: list[Figure] = measure(**kwargs)
    return figures


def main(argv: list[str]) -> int:
    name = argv[0]
    kwargs = json.loads(argv[1]) if len(argv) > 1 else {}
    try:
        figures = run(name, kwargs)
    except Exception as exc:  # reported as an ERROR row, with the traceback on stderr
        traceback.print_exc()
        figures = [Figure(name, name, None, "", error=f"{type(exc).__name__}: {exc}")]
    print(MARKER + json.dumps([f.as_dict() for f in figures]), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
