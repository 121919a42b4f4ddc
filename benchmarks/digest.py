"""``python -m benchmarks.digest [SCENARIO ...]``: sha256 of the shipped realistic scenarios'
result rows, replayed through the bench's pipeline as ``python -m benchmarks accuracy`` does.

A refactoring that must not change behaviour prints the same digests before and after it.
One line per scenario: the digest of the emulated CAN frames, of every result column (the
whole RESULT_DTYPE row, bytes as produced), of the events, and of the estimator's gradient
and sigma alone, so a change that touches only some columns can be told apart.
"""

from __future__ import annotations

import argparse
import hashlib

import numpy as np

from benchmarks.accuracy import SCENARIOS, _batches, emulate


def digests(name: str) -> tuple[str, str, str, str]:
    """(frames, all result columns, events, estimator gradient+sigma) sha256 of a scenario."""
    from bench.pipeline.steps import Pipeline
    from bench.replay.run import run_steps

    sim, config = emulate(name)
    rows, events, est = hashlib.sha256(), hashlib.sha256(), hashlib.sha256()
    for step in run_steps(Pipeline(config), _batches(sim.frames)):
        res = step.results
        rows.update(np.ascontiguousarray(res).tobytes())
        events.update(np.ascontiguousarray(step.events).tobytes())
        names = res.dtype.names or ()
        for col in ("gradient_signed", "gradient_sigma"):
            if col in names:
                est.update(np.ascontiguousarray(res[col]).tobytes())
    frames = hashlib.sha256(np.ascontiguousarray(sim.frames).tobytes()).hexdigest()[:16]
    return frames, rows.hexdigest()[:16], events.hexdigest()[:16], est.hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenarios", nargs="*", default=list(SCENARIOS))
    args = ap.parse_args()
    for name in args.scenarios:
        f, r, e, g = digests(name)
        print(f"{name:16s} frames {f}  rows {r}  events {e}  estimator {g}", flush=True)


if __name__ == "__main__":
    main()
