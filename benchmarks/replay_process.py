"""Whole-process ``bench replay`` of a candump log next to python-can's bare ``LogReader``
iteration of the same file, each in a fresh interpreter, alternated, best of ``repeat``.

Issue 29's figures (the best of ``repeat``, the median and the machine's load beside it: a
shared machine's figures move with it): the process's wall time from launch to exit
(imports, reading, the pipeline, the output file closed) for ``--csv`` (target >= 3x the
LogReader process's frame rate) and ``--parquet`` (>= 4x), without an output file
(informational), and the start-up: from launch to the first frames processed (decoded,
assembled, fused by the reference method: the end of the first step's first stage; target
<= 0.4 s) and, for information, to the first complete rows (the estimator's columns in
them), taken in the same processes (the child notes when ``Pipeline.reference`` and
``Pipeline.estimate`` first return).
"""

from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import ROOT, Figure, frames_for, warm_file

CSV_TARGET = 3.0
PARQUET_TARGET = 4.0
FIRST_STEP_TARGET_S = 0.4

_ANCHOR = """
import sys, can
n = 0
for _msg in can.LogReader(sys.argv[1]):
    n += 1
print(n)
"""

_BENCH = """
import importlib.abc, importlib.machinery, json, os, sys, time
first, first_row = [], []

class _NoteFirstStep(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name != "bench.pipeline.steps":
            return None
        sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        load = spec.loader.exec_module

        def exec_module(module):
            load(module)
            for name, into in (("reference", first), ("estimate", first_row)):
                def noted(self, arg, _method=getattr(module.Pipeline, name), _into=into):
                    out = _method(self, arg)
                    if not _into:
                        _into.append(time.time())
                    return out

                setattr(module.Pipeline, name, noted)

        spec.loader.exec_module = exec_module
        return spec

sys.meta_path.insert(0, _NoteFirstStep())
from bench.cli import program
sys.argv = ["bench", "replay", *sys.argv[1:], "-q"]
code = program()
with open(os.environ["BENCH_TIMES"], "w") as f:
    json.dump({"code": code, "first_step": first[0] if first else None,
               "first_row": first_row[0] if first_row else None}, f)
"""
"""The bench's child: the ``bench replay ARGS -q`` program with the end of its first pipeline
step's first stage noted (the first frames decoded, assembled and fused by the reference
method: ``first_step``) and of its second (the first complete rows, the estimator's columns
in them: ``first_row``). ``Pipeline.reference`` and ``Pipeline.estimate`` are wrapped when
``bench replay`` itself imports bench.pipeline.steps (an import hook), so the child imports
what the command does, in its order."""


def _cpu_s() -> float:
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


def _run(code: str, args: list[str], times: Path) -> tuple[float, dict[str, Any], str]:
    """Wall time of a fresh interpreter running ``code`` (launch to exit), what it noted in
    ``times`` (with ``cpu_s``, its CPU time: the steadier figure on a loaded machine), and
    its stderr."""
    times.unlink(missing_ok=True)
    env = {**os.environ, "BENCH_TIMES": str(times)}
    t0, cpu0 = time.time(), _cpu_s()
    proc = subprocess.run(
        [sys.executable, "-c", code, *args], cwd=ROOT, env=env, capture_output=True, text=True
    )
    dt = time.time() - t0
    noted: dict[str, Any] = json.loads(times.read_text()) if times.exists() else {}
    noted["cpu_s"] = _cpu_s() - cpu0
    if proc.returncode != 0:
        noted["error"] = (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]
    for key in ("first_step", "first_row"):
        if noted.get(key) is not None:
            noted[key] -= t0
    return dt, noted, proc.stderr


def warm_bytecode() -> None:
    """Byte-compile the bench's packages, as pip does for an installed one (python-can, the
    anchor's, has its bytecode): a checkout run with PYTHONDONTWRITEBYTECODE=1 (CI, some
    containers) has none and compiles each of its ~60 modules from source at every start."""
    import compileall

    for package in ("bench", "devices", "protocol"):
        compileall.compile_dir(ROOT / package, quiet=1)


def measure(n_frames: int = 1_200_000, repeat: int = 2, workdir: str | None = None) -> list[Figure]:
    from devices.writers import write_candump

    figures: list[Figure] = []
    with tempfile.TemporaryDirectory(prefix="bench-replay-process-", dir=workdir) as tmp:
        d = Path(tmp)
        log, times = d / "board.log", d / "times.json"
        write_candump(log, frames_for(n_frames))
        warm_file(log)
        warm_bytecode()
        variants = {
            "none": [],
            "csv": ["--csv", str(d / "out.csv")],
            "parquet": ["--parquet", str(d / "out.parquet")],
        }
        walls: dict[str, list[float]] = {}
        anchors: list[float] = []
        load = os.getloadavg()[0]
        best: dict[str, float] = {}
        cpu: dict[str, float] = {}
        first: dict[str, float] = {}
        first_row: dict[str, float] = {}
        errors: dict[str, str] = {}
        anchor_s = float("inf")
        for _ in range(repeat):  # alternated: the anchor and each variant under the same load
            dt, noted, _ = _run(_ANCHOR, [str(log)], times)
            anchor_s = min(anchor_s, dt)
            anchors.append(dt)
            cpu["anchor"] = min(cpu.get("anchor", float("inf")), noted["cpu_s"])
            for name, extra in variants.items():
                dt, noted, _ = _run(_BENCH, [str(log), *extra], times)
                if noted.get("error") or noted.get("code"):
                    errors[name] = noted.get("error") or f"exit {noted.get('code')}"
                    continue
                best[name] = min(best.get(name, float("inf")), dt)
                walls.setdefault(name, []).append(dt)
                cpu[name] = min(cpu.get(name, float("inf")), noted["cpu_s"])
                for key, into in (("first_step", first), ("first_row", first_row)):
                    if noted.get(key) is not None:
                        into[name] = min(into.get(name, float("inf")), noted[key])
        anchor = n_frames / anchor_s
        loads = f"load {load:.1f}-{os.getloadavg()[0]:.1f}"  # 1-min averages, start and end
        for name, label, target in (
            ("none", "replay process, candump .log", None),
            ("csv", "replay process, candump .log + CSV", CSV_TARGET),
            ("parquet", "replay process, candump .log + Parquet", PARQUET_TARGET),
        ):
            wall = best.get(name)
            median = statistics.median(walls[name]) if name in walls else None
            figures.append(
                Figure(
                    f"replay_process_{name}",
                    label,
                    n_frames / wall if wall else None,
                    "frames/s",
                    target=target,
                    on="ratio",
                    anchor=anchor,
                    anchor_label="python-can LogReader process",
                    detail=(
                        f"`bench replay LOG {' '.join(variants[name])}`, launch to exit "
                        f"{wall:.2f} s, best of {repeat} (median {median:.2f} s); LogReader "
                        f"process {anchor_s:.2f} s (median {statistics.median(anchors):.2f} s); "
                        f"CPU {cpu[name]:.2f} s, LogReader {cpu['anchor']:.2f} s; "
                        f"{n_frames} frames, {log.stat().st_size / 1e6:.0f} MB; {loads}"
                        if wall
                        else ""
                    ),
                    error=errors.get(name, ""),
                    extra={
                        "seconds": wall,
                        "median_seconds": median,
                        "anchor_seconds": anchor_s,
                        "anchor_median_seconds": statistics.median(anchors),
                        "load": loads,
                        "cpu_s": cpu.get(name),
                        "anchor_cpu_s": cpu.get("anchor"),
                    },
                )
            )
        figures.append(
            Figure(
                "replay_first_step",
                "  replay process, launch to first frames processed",
                min(first.values()) if first else None,
                "s",
                target=FIRST_STEP_TARGET_S,
                op="<=",
                detail=", ".join(f"{k} {v:.2f} s" for k, v in first.items()),
                extra=dict(first),
            )
        )
        figures.append(
            Figure(
                "replay_first_row",
                "  replay process, launch to first complete rows",
                min(first_row.values()) if first_row else None,
                "s",
                detail=", ".join(f"{k} {v:.2f} s" for k, v in first_row.items()),
                extra=dict(first_row),
            )
        )
    return figures


if __name__ == "__main__":  # pragma: no cover - convenience
    for fig in measure(**json.loads(sys.argv[1] if len(sys.argv) > 1 else "{}")):
        print(fig.label, fig.value, fig.unit, fig.ratio, fig.detail, fig.error)
