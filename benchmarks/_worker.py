"""Run one measurement in this process and print its figures as JSON (used by __main__).

    python -m benchmarks._worker NAME '{"kwarg": value}'

Progress goes to stderr; the last stdout line is ``FIGURES <json list>``.
"""

from __future__ import annotations

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


def run(name: str, kwargs: dict[str, Any]) -> list[Figure]:
    if name == "replay":
        from benchmarks import replay

        return replay.measure(out=_Emitting(), **kwargs)
    if name == "fusion":
        from benchmarks import fusion

        return fusion.measure(**kwargs)
    if name == "live_rate":
        from benchmarks import live

        return live.measure_rate(log=_log, **kwargs)
    if name == "latency":
        from benchmarks import live

        return live.measure_latency(**kwargs)
    if name == "replay_process":
        from benchmarks import replay_process

        return replay_process.measure(**kwargs)
    if name == "replay_memory":
        from benchmarks import outputs

        return outputs.measure_memory(out=_Emitting(), **kwargs)
    if name == "fleet":
        from benchmarks import outputs

        return outputs.measure_fleet(out=_Emitting(), **kwargs)
    if name == "accuracy":
        from benchmarks import accuracy

        return accuracy.measure(log=_log, **kwargs)
    if name == "random":
        from benchmarks import random_accuracy

        return random_accuracy.measure(log=_log, **kwargs)
    if name == "calibration":
        from benchmarks import calibration

        return calibration.measure(log=_log, **kwargs)
    if name == "rec_toggle":
        from benchmarks import rec_toggle

        return rec_toggle.measure(**kwargs)
    raise SystemExit(f"unknown measurement {name!r}")


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
