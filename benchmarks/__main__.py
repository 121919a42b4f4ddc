"""``python -m benchmarks [NAME ...] [--quick] [--json OUT] [--markdown OUT] [--only NAME ...]
[--random N [--seed S] [--scenarios-out DIR]]``

Runs every measurement (or the NAMEs given, e.g. ``accuracy``), each in a fresh Python
process, prints the table (figure, anchor, ratio, target, PASS/MISS) and the accuracy
tables per scenario with the machine it ran on, and writes it as JSON (default
``benchmarks/results.json``; a run of some measurements only replaces their figures there
and keeps the others'). The full run takes 3-5 minutes on 2 cores; ``--quick`` (smaller
files, short live runs) about one minute and is for smoke-testing the harness, not for
quoting. ``accuracy --random N --seed S`` scores N drawn runs (seeds S .. S+N-1,
benchmarks/random_runs.py) instead of the shipped scenarios, and writes their scenario
files to ``--scenarios-out`` (default logs/random); the shipped table's figures stay in the
JSON beside them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from benchmarks._worker import MARKER, PARTIAL
from benchmarks.accuracy import is_accuracy
from benchmarks.accuracy import markdown as accuracy_markdown
from benchmarks.accuracy import print_tables as print_accuracy
from benchmarks.calibration import is_calibration, print_calibration
from benchmarks.calibration import markdown as calibration_markdown
from benchmarks.common import ROOT, Figure, fmt_value, machine_info
from benchmarks.random_accuracy import is_random, print_random
from benchmarks.random_accuracy import markdown as random_markdown

DEFAULT_JSON = ROOT / "benchmarks" / "results.json"

# name, kwargs (full), kwargs (quick), timeout s (full)
PLAN: list[tuple[str, dict[str, Any], dict[str, Any], float]] = [
    ("replay", {"n_frames": 1_000_000, "repeat": 3}, {"n_frames": 200_000, "repeat": 2}, 480),
    # issue 29: whole-process replay against a LogReader process, and the start-up
    ("replay_process", {"n_frames": 1_200_000, "repeat": 2}, {"n_frames": 200_000}, 300),
    ("fusion", {"n_samples": 1_000_000, "repeat": 5}, {"n_samples": 300_000, "repeat": 3}, 120),
    ("replay_memory", {"sizes": [1_000_000, 10_000_000]}, {"sizes": [1_000_000, 2_000_000]}, 900),
    (
        "fleet",
        {"n_logs": 20, "frames_per_log": 300_000},
        {"n_logs": 20, "frames_per_log": 30_000},
        600,
    ),
    ("live_rate", {"confirm_s": 30.0, "probe_s": 5.0}, {"confirm_s": 5.0, "probe_s": 2.0}, 480),
    ("latency", {"seconds": 30.0, "tui": False}, {"seconds": 8.0, "tui": False}, 120),
    ("latency", {"seconds": 30.0, "tui": True}, {"seconds": 8.0, "tui": True}, 120),
    ("accuracy", {}, {}, 300),
    (
        "rec_toggle",
        {"before_s": 5.0, "after_s": 10.0, "toggles": 3},
        {"before_s": 2.0, "after_s": 3.0, "toggles": 1},
        180,
    ),
]


RANDOM_PLAN: dict[str, tuple[str, dict[str, Any], float]] = {
    # measurement named on the command line -> (random measurement, quick kwargs, s per run)
    "accuracy": ("random", {"n": 3}, 20.0),
    "calibration": ("calibration", {"n": 3}, 20.0),
}
"""What ``--random N`` turns a measurement into; ``calibration`` is only ever random (50
runs from seed 5000 without ``--random``). Neither is part of the full run."""


def run_worker(name: str, kwargs: dict[str, Any], timeout: float) -> list[Figure]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH", "")]))
    cmd = [sys.executable, "-m", "benchmarks._worker", name, json.dumps(kwargs)]
    try:
        proc = subprocess.run(
            cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True, timeout=timeout, check=False
        )
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        got = [
            Figure.from_dict(json.loads(line[len(PARTIAL) :]))
            for line in out.splitlines()
            if line.startswith(PARTIAL)
        ]
        return [
            *got,
            Figure(name, f"{name} (rest)", None, "", error=f"timed out after {timeout:.0f} s"),
        ]
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(MARKER):
            return [Figure.from_dict(d) for d in json.loads(line[len(MARKER) :])]
    return [Figure(name, name, None, "", error=f"worker exited {proc.returncode} without figures")]


def _anchor_text(f: Figure) -> str:
    if f.anchor is None:
        return "-"
    return fmt_value(f.anchor, f.unit)


def _ratio_text(f: Figure) -> str:
    r = f.ratio
    return "-" if r is None else f"{r:.2f}x"


def print_table(
    figures: list[Figure], machine: dict[str, Any], elapsed: float, quick: bool
) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    if not console.is_terminal:  # piped or in CI: room for the whole table
        console = Console(width=150)
    accuracy_figures = [f for f in figures if is_accuracy(f)]
    random_figures = [f for f in figures if is_random(f)]
    calibration_rows = [f for f in figures if is_calibration(f)]
    figures = [f for f in figures if not is_accuracy(f) and not is_random(f)]
    title = "gradient bench benchmarks" + (
        " (--quick: smoke test, not for quoting)" if quick else ""
    )
    table = Table(title=title, title_justify="left")
    for col in ("figure", "value", "anchor (same run, same file)", "ratio", "target", ""):
        table.add_column(
            col, justify="right" if col in ("value", "ratio") or "anchor" in col else "left"
        )
    style = {"PASS": "bold green", "MISS": "bold red", "ERROR": "bold red", "INFO": "dim"}
    for f in figures:
        table.add_row(
            f.label,
            fmt_value(f.value, f.unit),
            _anchor_text(f),
            _ratio_text(f),
            f.target_text(),
            f"[{style[f.status]}]{f.status}[/]",
        )
    if figures:
        console.print(table)
    for f in figures:
        note = f.error or f.detail
        if note:
            anchor = f" [anchor: {f.anchor_label}]" if f.anchor_label else ""
            console.print(f"  [bold]{f.label}[/]: {note}{anchor}", highlight=False)
    if accuracy_figures:
        print_accuracy(accuracy_figures, console)
    if random_figures:
        print_random(random_figures, console)
    if calibration_rows:
        print_calibration(calibration_rows, console)
    console.print(machine_line(machine) + f"; total {elapsed:.0f} s", highlight=False)


def machine_line(m: dict[str, Any]) -> str:
    return (
        f"machine: {m['cpu']}, {m['cores']} cores ({m['cores_usable']} usable), "
        f"{m['memory_gb']} GB, {m['os']}; Python {m['python']}, numpy {m['numpy']}, "
        f"python-can {m['python-can']}, mcap {m['mcap']}, textual {m['textual']}; "
        f"commit {m['commit']}; load avg at start {m['loadavg_at_start'][0]}; "
        f"{m.get('live_cpu', 'live path placement not recorded')}"
    )


def markdown(figures: list[Figure], machine: dict[str, Any], when: str) -> str:
    lines = []
    general = [f for f in figures if not is_accuracy(f) and not is_random(f)]
    if general:
        lines += [
            "| figure | value | anchor (same run, same file) | ratio | target | result |",
            "|---|---:|---:|---:|---|---|",
        ]
    for f in general:
        anchor = _anchor_text(f)
        if f.anchor_label and f.anchor is not None:
            anchor = f"{anchor} ({f.anchor_label})"
        lines.append(
            f"| {f.label} | {fmt_value(f.value, f.unit)} | {anchor} | {_ratio_text(f)} | "
            f"{f.target_text()} | {f.status} |"
        )
    lines.append("")
    accuracy = accuracy_markdown(figures)
    if accuracy:
        lines += [accuracy]
    randoms = [f for f in figures if is_random(f)]
    if randoms:
        lines += [random_markdown(randoms)]
    calibration_rows = [f for f in figures if is_calibration(f)]
    if calibration_rows:
        lines += [calibration_markdown(calibration_rows)]
    lines.append(f"{when}, {machine_line(machine)}.")
    return "\n".join(lines) + "\n"


def _kept(path: Path, selected: set[str]) -> tuple[list[Figure], list[dict[str, Any]]]:
    """Figures and runs of the measurements not run now, from an earlier results file."""
    try:
        doc = json.loads(path.read_text())
        runs = [r for r in doc.get("runs", []) if r.get("name") not in selected]
        for r in runs:  # where and when those figures were measured
            r.setdefault("started", doc.get("started"))
            r.setdefault("machine", doc.get("machine"))
        keep = {r["name"] for r in runs}
        figures = [
            Figure.from_dict(d) for d in doc.get("figures", []) if _measurement_of(d) in keep
        ]
    except (OSError, ValueError, KeyError, TypeError):
        return [], []
    return figures, runs


def _measurement_of(fig: dict[str, Any]) -> str:
    """Which PLAN measurement made a figure (its key's first word; live_max_rate* = live_rate)."""
    key = str(fig.get("key", ""))
    if key.startswith("live_max_rate"):
        return "live_rate"
    if key.startswith(("replay_process_", "replay_first_step", "replay_first_row")):
        return "replay_process"
    if key.startswith("replay_rss_"):  # outputs.measure_memory's figures
        return "replay_memory"
    if key.startswith(("replay_", "read_", "mcap_", "pipeline_")):
        return "replay"
    if key.startswith("random_"):
        return "random"
    return key.split("_", 1)[0]


def random_plan(
    args: argparse.Namespace, selected: set[str]
) -> tuple[list[tuple[str, dict[str, Any], dict[str, Any], float]], set[str]]:
    """The measurements to run when random ones are asked for: with ``--random N`` each
    selected one RANDOM_PLAN knows (all of them when none is named) on seeds --seed ..
    --seed + N - 1; without it, ``calibration`` on 50 runs from --seed and the rest as
    PLAN has them."""
    n = args.random if args.random is not None else 50
    chosen = selected or set(RANDOM_PLAN)
    if args.random is not None:
        unknown = sorted(chosen - set(RANDOM_PLAN))
        if unknown:
            raise SystemExit(
                f"python -m benchmarks: error: --random applies to {', '.join(RANDOM_PLAN)}, "
                f"not {unknown[0]}"
            )
    plan = []
    for name, full, quick, timeout in PLAN:
        if name in chosen and (args.random is None or name not in RANDOM_PLAN):
            plan.append((name, full, quick, timeout))
    for name in sorted(chosen & set(RANDOM_PLAN)):
        if args.random is None and any(p[0] == name for p in PLAN):
            continue
        random_name, quick, per_run = RANDOM_PLAN[name]
        full = {"n": n, "seed": args.seed}
        if args.scenarios_out and random_name == "random":
            full["scenarios_out"] = args.scenarios_out
        plan.append((random_name, full, {**full, **quick}, 120.0 + per_run * n))
    return plan, {p[0] for p in plan}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.split("\n\n")[1])
    ap.add_argument("--quick", action="store_true", help="~1 minute smoke run (small files)")
    ap.add_argument("--json", metavar="OUT", default=str(DEFAULT_JSON), help="results file")
    ap.add_argument("--markdown", metavar="OUT", help="also write the table as Markdown")
    names = sorted({p[0] for p in PLAN} | set(RANDOM_PLAN))
    ap.add_argument(
        "names",
        nargs="*",
        metavar="NAME",
        help=f"run only these measurements ({', '.join(names)}); default: all",
    )
    ap.add_argument("--only", nargs="+", choices=names, help="the same as NAMEs")
    ap.add_argument(
        "--random",
        type=int,
        metavar="N",
        help="score N drawn runs instead of the shipped scenarios (accuracy)",
    )
    ap.add_argument(
        "--seed", type=int, default=5000, metavar="S", help="first seed of --random (5000)"
    )
    ap.add_argument(
        "--scenarios-out",
        metavar="DIR",
        help="where --random writes the drawn scenarios (default logs/random)",
    )
    args = ap.parse_args(argv)
    if args.random is not None and args.random < 1:
        ap.error(f"--random must be at least 1, got {args.random}")
    if args.seed < 0:
        ap.error(f"--seed must be >= 0, got {args.seed}")
    unknown = sorted(set(args.names) - set(names))
    if unknown:
        ap.error(f"unknown measurement {unknown[0]!r} (expected one of {', '.join(names)})")
    selected = set(args.names) | set(args.only or ())
    plan = PLAN
    if args.random is not None or "calibration" in selected:
        plan, selected = random_plan(args, selected)
    machine = machine_info()
    started = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    t0 = time.monotonic()
    figures: list[Figure] = []
    runs = []
    for name, full, quick, timeout in plan:
        if selected and name not in selected:
            continue
        kwargs = quick if args.quick else full
        print(f"benchmarks: {name} {kwargs} ...", file=sys.stderr, flush=True)
        t = time.monotonic()
        got = run_worker(name, kwargs, timeout if not args.quick else timeout / 2)
        runs.append(
            {
                "name": name,
                "kwargs": kwargs,
                "seconds": round(time.monotonic() - t, 1),
                "started": started,
                "machine": machine,
            }
        )
        figures += got
    elapsed = time.monotonic() - t0
    machine["loadavg_at_end"] = [round(x, 2) for x in os.getloadavg()]
    print_table(figures, machine, elapsed, args.quick)
    out = Path(args.json)
    if selected:
        figures_all, runs_all = _kept(out, selected)
        figures, runs = figures_all + figures, runs_all + runs
    doc = {
        "started": started,
        "quick": args.quick,
        "elapsed_s": round(elapsed, 1),
        "machine": machine,
        "runs": runs,
        "figures": [f.as_dict() for f in figures],
        "summary": {
            s: sum(f.status == s for f in figures) for s in ("PASS", "MISS", "ERROR", "INFO")
        },
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(doc, indent=2, default=str) + "\n")
    print(f"benchmarks: wrote {out}", file=sys.stderr)
    if args.markdown:
        Path(args.markdown).write_text(markdown(figures, machine, started))
        print(f"benchmarks: wrote {args.markdown}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
