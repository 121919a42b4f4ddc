"""Memory of a replay writing CSV and Parquet as the log grows, and `bench fleet`'s speed-up.

* Peak RSS: ``bench replay LOG --csv OUT --parquet OUT`` in a fresh process per log size
  (1 M and 10 M frames of the 1 kHz board by default); the process reports its own peak
  (``VmHWM``) at the end. Flat means the largest is within 1.5x of the smallest (issue 17:
  a replay never holds all its results at once).
* Fleet: 20 emulated candump logs replayed by ``run_fleet`` on a LocalCluster of 1 and of 2
  worker processes; the figure is the time from the first task submitted to the last row
  gathered (cluster start-up, ~2-5 s, reported beside it), and the speed-up 1 -> 2.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.common import ROOT, Figure, frames_for

FLAT_TARGET = 1.5

_CHILD = """
import json, sys
from bench.cli import main
code = main(["replay", sys.argv[1], "--csv", sys.argv[2], "--parquet", sys.argv[3], "-q"])
hwm = [line for line in open("/proc/self/status") if line.startswith("VmHWM:")]
print(json.dumps({"code": code, "maxrss_kb": int(hwm[0].split()[1])}))
"""
"""The measured process's own peak (VmHWM: of its address space since exec; ru_maxrss would
also count the benchmark parent's memory, which Linux carries across fork and exec)."""


def _write_log(path: Path, n_frames: int) -> None:
    """A candump log of ``n_frames`` frames of one continuous board run."""
    from devices.writers import write_candump

    write_candump(path, frames_for(n_frames))


def measure_memory(sizes: tuple[int, ...] = (1_000_000, 10_000_000), workdir: str | None = None,
                   out: list[Figure] | None = None) -> list[Figure]:  # fmt: skip
    figures: list[Figure] = out if out is not None else []
    peaks: dict[int, float] = {}
    with tempfile.TemporaryDirectory(prefix="bench-mem-", dir=workdir) as tmp:
        d = Path(tmp)
        for n in sizes:
            log = d / f"board-{n}.log"
            _write_log(log, n)
            t0 = time.perf_counter()
            proc = subprocess.run(
                [sys.executable, "-c", _CHILD, str(log), str(d / "o.csv"), str(d / "o.parquet")],
                cwd=ROOT, capture_output=True, text=True, check=False,
            )  # fmt: skip
            dt = time.perf_counter() - t0
            try:
                got = json.loads(proc.stdout.strip().splitlines()[-1])
            except (IndexError, ValueError):
                figures.append(Figure(f"replay_rss_{n}", f"peak RSS, replay {n / 1e6:g} M frames",
                                      None, "MB", error=proc.stderr[-300:]))  # fmt: skip
                continue
            peaks[n] = got["maxrss_kb"] / 1024.0
            figures.append(
                Figure(
                    f"replay_rss_{n}",
                    f"peak RSS, replay + CSV + Parquet, {n / 1e6:g} M frames",
                    peaks[n],
                    "MB",
                    detail=f"fresh process, {log.stat().st_size / 1e6:.0f} MB log, {dt:.1f} s, "
                    f"CSV {(d / 'o.csv').stat().st_size / 1e6:.0f} MB, "
                    f"Parquet {(d / 'o.parquet').stat().st_size / 1e6:.0f} MB",
                    error="" if got["code"] == 0 else f"exit {got['code']}",
                )
            )
            log.unlink()
    if len(peaks) >= 2:
        lo, hi = min(peaks), max(peaks)
        figures.append(
            Figure(
                "replay_rss_growth",
                f"  peak RSS {hi / 1e6:g} M / {lo / 1e6:g} M frames",
                peaks[hi] / peaks[lo],
                "x",
                target=FLAT_TARGET,
                op="<=",
                detail="flat memory: the replay streams its results to the files",
            )
        )
    return figures


def _fleet_logs(d: Path, n_logs: int, frames_per_log: int) -> list[str]:
    from devices.writers import write_candump

    frames = frames_for(frames_per_log)
    paths = []
    for i in range(n_logs):
        part = frames.copy()
        part["t"] = part["t"] + i * 1e-6  # every log a different file (its own content hash)
        p = d / f"train{i:02d}.log"
        write_candump(p, part)
        paths.append(str(p))
    return paths


def measure_fleet(n_logs: int = 20, frames_per_log: int = 300_000, workdir: str | None = None,
                  out: list[Figure] | None = None) -> list[Figure]:  # fmt: skip
    from rich.console import Console

    from bench.fleet.run import run_fleet

    figures: list[Figure] = out if out is not None else []
    times: dict[int, float] = {}
    with tempfile.TemporaryDirectory(prefix="bench-fleet-", dir=workdir) as tmp:
        d = Path(tmp)
        paths = _fleet_logs(d, n_logs, frames_per_log)
        for workers in (1, 2):
            t0 = time.perf_counter()
            outcome = run_fleet(paths, d / f"out{workers}", workers=workers,
                                console=Console(quiet=True), progress=False)  # fmt: skip
            total = time.perf_counter() - t0
            times[workers] = outcome.wall_s
            figures.append(
                Figure(
                    f"fleet_{workers}",
                    f"fleet, {n_logs} logs, {workers} worker{'s' if workers > 1 else ''}",
                    outcome.frames / outcome.wall_s,
                    "frames/s",
                    detail=f"{outcome.frames} frames in {outcome.wall_s:.2f} s from first task "
                    f"to last row ({total:.1f} s with cluster start and stop); "
                    f"{outcome.failed} failed",
                    error="" if not outcome.failed else f"{outcome.failed} logs failed",
                )
            )
    if len(times) == 2:
        figures.append(
            Figure(
                "fleet_speedup",
                "  fleet speed-up 1 -> 2 workers",
                times[1] / times[2],
                "x",
                detail="same 20 logs, LocalCluster of processes on 127.0.0.1",
            )
        )
    return figures


def measure(**kwargs: Any) -> list[Figure]:  # pragma: no cover - convenience
    return [*measure_memory(), *measure_fleet(**kwargs)]
