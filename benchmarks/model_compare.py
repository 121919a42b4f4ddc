"""Issue 26's explicit model (bench.fusion.model) against today's estimator.

Each run (a shipped scenario or a random seed) is emulated and replayed through the
bench's pipeline as the accuracy benchmark does, with a :class:`ModelLog` on the
estimator: the model's forward pass and its RTS smoother run over what the joint filter
was given. All three are scored by :func:`benchmarks.accuracy.scores` against the
emulator's truth; for the wheel-scale error the emulated one is beside the estimate.

    python -m benchmarks.model_compare --shipped
    python -m benchmarks.model_compare --random 20 --seed 1000   # seeds 1000..1019
    ... jerk_psd=0.2 vibration_w_mps2=0.02                       # model parameters
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from benchmarks.accuracy import SCENARIOS, scores

METHODS = ("today", "filtered", "smoothed")


def _replay(sim: Any, config: Any, **prm: float) -> dict[str, Any]:
    """Today's estimator and the model's two passes over one emulated run."""
    from bench.fusion.model.log import ModelLog
    from bench.pipeline.steps import Pipeline
    from bench.replay.run import run_steps
    from benchmarks.accuracy import _batches

    pipeline = Pipeline(config)
    log = ModelLog()
    pipeline.estimator.log = log  # type: ignore[attr-defined]  # the real Estimator
    counter0 = int(sim.truth["counter"][0]) if len(sim.truth) else 0
    n, signed, sigma = [], [], []
    for step in run_steps(pipeline, _batches(sim.frames)):
        res = step.results
        if len(res):
            n.append(res["n"] - counter0)
            signed.append(res["gradient_signed"].copy())
            sigma.append(res["gradient_sigma"].copy())
    rows = np.concatenate(n).astype(np.int64)
    truth = sim.truth["gradient_permil"]
    sm = log.smooth(config, **prm)
    bp = sim.scenario.body_pitch
    return {
        "today": scores(np.concatenate(signed), rows, truth, np.concatenate(sigma), True),
        "filtered": scores(sm.filtered, rows, truth, sm.filtered_sigma, True),
        "smoothed": scores(sm.smoothed, rows, truth, sm.smoothed_sigma, True),
        "wheel": [sm.wheel_scale, sm.wheel_scale_sigma, sim.scenario.odometer.wheel_diameter_error],
        "compliance": [
            sm.compliance_deg_per_mps2,
            sm.compliance_sigma_deg_per_mps2,
            bp.compliance_deg_per_mps2 if bp.enabled else 0.0,
        ],
    }


def compare_shipped(name: str, **prm: float) -> dict[str, Any]:
    from benchmarks.accuracy import emulate

    sim, config = emulate(name)
    return {"run": name, **_replay(sim, config, **prm)}


def compare_seed(seed: int, **prm: float) -> dict[str, Any]:
    from benchmarks.accuracy import scenario_config
    from benchmarks.random_runs import draw
    from devices.emulator import simulate

    d = draw(seed)
    out = _replay(simulate(d.scenario), scenario_config(d.scenario), **prm)
    return {"run": seed, "odometer": d.odometer, "summary": d.summary, **out}


def _one(job: tuple[str | int, dict[str, float]]) -> dict[str, Any]:
    run, prm = job
    return compare_seed(run, **prm) if isinstance(run, int) else compare_shipped(run, **prm)


def compare(runs: list[str | int], processes: int = 2, **prm: float) -> list[dict[str, Any]]:
    """Every run, over ``processes`` spawned workers (numba's cache serves each)."""
    jobs = [(r, prm) for r in runs]
    if processes <= 1 or len(jobs) <= 1:
        return [_one(j) for j in jobs]
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=processes, mp_context=ctx) as pool:
        return list(pool.map(_one, jobs))


def summary(results: list[dict[str, Any]]) -> dict[str, dict[str, float | None]]:
    """Per method: the median and the worst of each metric over the runs."""
    out: dict[str, dict[str, float | None]] = {}
    for m in METHODS:
        row: dict[str, float | None] = {}
        for metric, worst in (("rms", max), ("p99", max), ("avail", min), ("cover", min)):
            vals = [r[m][metric] for r in results if r[m][metric] is not None]
            row[f"{metric}_median"] = float(np.median(vals)) if vals else None
            row[f"{metric}_worst"] = float(worst(vals)) if vals else None
        row["wrong_mean"] = float(np.mean([r[m]["wrong"] or 0.0 for r in results]))
        out[m] = row
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.model_compare")
    ap.add_argument("--shipped", action="store_true", help="the shipped scenarios")
    ap.add_argument("--random", type=int, default=0, metavar="N", help="N random seeds")
    ap.add_argument("--seed", type=int, default=1000, help="the first random seed")
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--json", action="store_true", help="every run's scores as JSON")
    ap.add_argument("--markdown", action="store_true", help="one table (docs/ESTIMATOR.md)")
    ap.add_argument("prm", nargs="*", help="model parameters NAME=VALUE (ModelParams)")
    args = ap.parse_args(argv)
    prm = {k: float(v) for k, v in (a.split("=", 1) for a in args.prm)}
    runs: list[str | int] = list(SCENARIOS) if args.shipped else []
    runs += list(range(args.seed, args.seed + args.random))
    results = compare(runs, args.processes, **prm)
    if args.json:
        print(json.dumps(results))
        return 0
    if args.markdown:
        print("\n".join(markdown(results)))
        return 0
    for r in results:
        cells = [f"{m} {_cells(r[m])}" for m in METHODS]
        e, es, et = r["wheel"]
        wheel = f"E {100 * e:+.2f}+-{100 * es:.2f} % (true {100 * et:+.2f})"
        c, cs, ct = r["compliance"]
        comp = f"C {c:+.3f}+-{cs:.3f} deg/(m/s^2) (true {ct:+.3f})"
        print(f"{r['run']}: " + " | ".join(cells) + " | " + wheel + " | " + comp)
    print(json.dumps(summary(results), indent=1))
    return 0


def markdown(results: list[dict[str, Any]]) -> list[str]:
    """One row per run, RMS / p99 / availability / wrong / coverage of each method."""
    head = "| run | " + " | ".join(f"{m} RMS, p99, avail %, wrong %, cover %" for m in METHODS)
    lines = [
        head + " | E found (true) | C found (true), deg per m/s^2 |",
        "|---" * (len(METHODS) + 3) + "|",
    ]
    for r in results:
        cells = [_cells(r[m], ", ") for m in METHODS]
        e, es, et = r["wheel"]
        wheel = f"{100 * e:+.2f} +- {100 * es:.2f} % ({100 * et:+.2f})"
        c, cs, ct = r["compliance"]
        comp = f"{c:+.3f} +- {cs:.3f} ({ct:+.3f})"
        lines.append(f"| {r['run']} | " + " | ".join(cells) + f" | {wheel} | {comp} |")
    return lines


def _cells(s: dict[str, Any], sep: str = " ") -> str:
    """RMS, p99, availability, wrong, coverage of one method (names unless sep is given)."""
    named = sep == " "
    parts = [
        (key, _f(s[key], digits)) for key, digits in
        (("rms", 2), ("p99", 2), ("avail", 1), ("wrong", 2), ("cover", 1))
    ]  # fmt: skip
    return sep.join(f"{k} {v}" if named else v for k, v in parts)


def _f(v: float | None, digits: int = 3) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
