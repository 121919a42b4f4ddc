"""`bench fleet`'s client: one Dask task per log, a progress bar, ``logs.parquet``, a table.

The same code drives a :class:`dask.distributed.LocalCluster` (processes on 127.0.0.1, the
default) and an existing cluster (``--scheduler tcp://HOST:PORT``): the client only maps
:func:`bench.fleet.task.replay_one` over the paths and gathers rows as they finish. Every
worker writes its own log's partition of ``DIR/results/`` (so ``DIR`` must be the same path
on every worker); the client alone writes ``DIR/logs.parquet``.
"""

from __future__ import annotations

import glob
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
from rich.console import Console, JustifyMethod
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from bench.errors import BenchError
from bench.fleet.summary import logs_table
from bench.fleet.task import RESULTS_DIR, partition, replay_one
from devices.formats import log_formats

LOGS_FILE = "logs.parquet"


@dataclass
class FleetOutcome:
    rows: list[dict[str, Any]]  # this run's logs, in input order
    replayed: int = 0
    skipped: int = 0
    failed: int = 0
    frames: int = 0
    wall_s: float = 0.0
    workers: int = 0
    kept: list[dict[str, Any]] = field(default_factory=list)  # earlier rows not in this run


def expand(patterns: list[str]) -> list[str]:
    """Paths from files, folders and glob patterns (``**`` recursive), in order, each once.

    A folder stands for every log under it (any depth, by extension), as ``DIR/**/*``
    would: ``bench fleet logs/`` is what a bench engineer types first."""
    out: list[str] = []
    seen: set[str] = set()
    for pat in patterns:
        if glob.has_magic(pat) or os.path.isdir(pat):
            where = os.path.join(glob.escape(pat), "**", "*") if os.path.isdir(pat) else pat
            matches = sorted(glob.glob(where, recursive=True))
            matches = [m for m in matches if Path(m).suffix.lower() in log_formats()]
        else:
            matches = [pat]
        for m in matches:
            key = os.path.abspath(m)
            if key not in seen:
                seen.add(key)
                out.append(m)
    return out


WORKERS_PER_CPU = 4
"""Local workers allowed per CPU: a worker is a process (~100 MB, a Dask nanny, sockets);
past a few per CPU more only cost memory and start-up, never speed."""


def usable_cpus() -> int:
    cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    return len(cpus) if cpus else (os.cpu_count() or 1)


def check_workers(workers: int | None) -> None:
    """BenchError unless ``--workers`` is between 1 and WORKERS_PER_CPU per usable CPU."""
    if workers is None:
        return
    if workers < 1:
        raise BenchError(f"--workers must be >= 1, got {workers}")
    cpus = usable_cpus()
    most = WORKERS_PER_CPU * cpus
    if workers > most:
        raise BenchError(
            f"--workers {workers}: at most {most} here ({WORKERS_PER_CPU} per CPU, {cpus} "
            "CPUs; each worker is a process); more machines: --scheduler tcp://HOST:PORT"
        )


def previous_rows(out_dir: Path) -> list[dict[str, Any]]:
    """The rows of an earlier run's logs.parquet (none when there is none or it is unreadable)."""
    path = out_dir / LOGS_FILE
    if not path.exists():
        return []
    try:
        return pq.read_table(path).to_pylist()
    except Exception:  # an unreadable index is rebuilt: every log is replayed again
        return []


def _client(workers: int | None, scheduler: str | None) -> tuple[Any, Any]:
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except OSError as exc:
            raise BenchError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        except (ValueError, TypeError) as exc:  # dask's parse of the address
            raise BenchError(
                f"--scheduler {scheduler!r}: not a scheduler address ({exc}); expected "
                "tcp://HOST:PORT"
            ) from None
    if workers is None:
        workers = usable_cpus()
    cluster = LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=logging.ERROR,
    )
    return Client(cluster), cluster


def run_fleet(
    paths: list[str],
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    config_toml: str | None = None,
    console: Console | None = None,
    progress: bool = True,
    smooth: bool = False,
) -> FleetOutcome:
    """Replay every log (one task each), write ``out_dir/logs.parquet``; rows in input order.
    ``smooth``: with the smoother's columns; a log done before is redone unless it was
    done the same way."""
    from dask.distributed import as_completed

    out = Path(out_dir)
    (out / RESULTS_DIR).mkdir(parents=True, exist_ok=True)
    before = previous_rows(out)
    done = {
        r["content_hash"]: r
        for r in before
        if r.get("error") is None
        and r.get("content_hash")
        and (partition(out, r["log"]) / "part-0.parquet").exists()
        and bool(r.get("smoothed")) == smooth
    }
    console = console or Console(stderr=True)
    client, cluster = _client(workers, scheduler)
    rows: dict[int, dict[str, Any]] = {}
    start = time.perf_counter()
    frames = 0
    try:
        n_workers = len(client.scheduler_info().get("workers", {}))
        futures = client.map(
            replay_one,
            paths,
            out_dir=str(out.resolve()),
            config_toml=config_toml,
            done=frozenset(done),
            smooth=smooth,
            pure=False,
        )
        index = {f.key: i for i, f in enumerate(futures)}
        bar = Progress(
            TextColumn("fleet"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("logs  {task.fields[rate]}"),
            TimeElapsedColumn(),
            console=console,
            transient=True,
            disable=not progress,
        )
        with bar:
            task = bar.add_task("logs", total=len(paths), rate="")
            for fut in as_completed(futures):
                i = index[fut.key]
                try:
                    row = fut.result()
                except Exception as exc:  # a worker died under this log: still a row
                    row = {"path": paths[i], "error": f"task failed: {type(exc).__name__}: {exc}"}
                rows[i] = row
                frames += row.get("frames") or 0
                elapsed = time.perf_counter() - start
                bar.update(task, advance=1, rate=f"{frames / elapsed / 1e3:,.0f} k frames/s")
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    ordered = []
    for i in range(len(paths)):
        row = rows[i]
        if row.pop("skipped", False):
            old = dict(done[row["content_hash"]])
            old["path"] = row["path"]
            row = old
            row["_skipped"] = True
        ordered.append(row)
    this_run = {r.get("content_hash") for r in ordered if r.get("content_hash")}
    this_paths = {os.path.abspath(r["path"]) for r in ordered}
    kept = [
        r
        for r in before
        if r.get("content_hash") not in this_run and os.path.abspath(r["path"]) not in this_paths
    ]
    outcome = FleetOutcome(
        rows=ordered,
        skipped=sum(1 for r in ordered if r.get("_skipped")),
        failed=sum(1 for r in ordered if r.get("error")),
        frames=frames,
        wall_s=time.perf_counter() - start,
        workers=n_workers,
        kept=kept,
    )
    outcome.replayed = len(ordered) - outcome.skipped - outcome.failed
    write_logs(out, _unique([*kept, *ordered]))
    return outcome


def _unique(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per log id (two paths with the same bytes are one log: the first is kept)."""
    seen: set[str] = set()
    out = []
    for r in rows:
        key = r.get("log") or r["path"]
        if key in seen:
            continue
        seen.add(key)
        out.append(r)
    return out


def write_logs(out: Path, rows: list[dict[str, Any]]) -> None:
    """``logs.parquet``, replaced atomically (a reader never sees half a file)."""
    tmp = out / f".{LOGS_FILE}.tmp"
    pq.write_table(logs_table(rows), tmp, compression="zstd")
    os.replace(tmp, out / LOGS_FILE)


def fleet_table(outcome: FleetOutcome, limit: int = 40) -> Table:
    """The console table: one row per log of this run (failed ones first), at most ``limit``."""
    table = Table(title=f"fleet: {len(outcome.rows)} logs")
    justify: JustifyMethod
    for name, justify in (
        ("log", "left"),
        ("frames", "right"),
        ("valid %", "right"),
        ("excluded s ch1/2/3", "right"),
        ("|ref-est| permil", "right"),
        ("status", "left"),
    ):
        table.add_column(name, justify=justify, no_wrap=True)
    rows = sorted(outcome.rows, key=lambda r: r.get("error") is None)
    for r in rows[:limit]:
        if r.get("error"):
            table.add_row(Path(r["path"]).name, "-", "-", "-", "-", "[red]FAILED[/]")
            continue
        ex = "/".join(f"{r.get(f'excluded_ch{k}_s') or 0:.1f}" for k in (1, 2, 3))
        diff = r.get("max_ref_minus_est_permil")
        valid = r.get("valid_pct")
        table.add_row(
            Path(r["path"]).name,
            f"{r.get('frames') or 0:,}",
            "-" if valid is None else f"{valid:.1f}",
            ex,
            "-" if diff is None else f"{diff:.2f}",
            "skipped" if r.get("_skipped") else "replayed",
        )
    if len(rows) > limit:
        table.caption = f"... and {len(rows) - limit} more in logs.parquet"
    return table
