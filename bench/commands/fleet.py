"""`bench fleet LOG_OR_GLOB... --out DIR`: replay many logs in parallel on Dask distributed."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from rich.console import Console

from bench.errors import BenchError
from bench.sinks.console import print_whole


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fleet",
        help="replay many logs in parallel (Dask) into one Parquet dataset and a per-log table",
        description="Replay logs in parallel on Dask distributed: a local cluster of worker "
        "processes by default, or an existing cluster (--scheduler). Writes DIR/results/ (every "
        "result row, hive-partitioned by `log`) and DIR/logs.parquet (one row per log). Logs "
        "already replayed into DIR (same content hash) are skipped. See docs/FLEET.md.",
    )
    p.add_argument(
        "logs",
        nargs="+",
        metavar="LOG_OR_GLOB",
        help="log files, folders (every log under them) or glob patterns",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers", type=int, metavar="N", help="local worker processes (default: one per CPU)"
    )
    where.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="use an existing Dask cluster (its workers must see DIR and the logs at these paths)",
    )
    p.add_argument(
        "--config",
        help="calibration config (TOML) for every log; default: an MCAP log's recorded one, "
        "else the ICD's nominal values",
    )
    p.add_argument(
        "--smooth",
        action="store_true",
        help="also gradient_smoothed_permil and its sigma in results/ and the wheel-diameter "
        "error found in logs.parquet (each log read twice; see bench replay --smooth)",
    )
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar or table")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.config import load_config
    from bench.fleet.run import LOGS_FILE, check_workers, expand, fleet_table, run_fleet
    from bench.sinks.paths import check_output_dir
    from devices.paths import check_clashes

    check_workers(args.workers)
    paths = expand(args.logs)
    if not paths:
        raise BenchError(f"no logs match {' '.join(args.logs)}")
    check_clashes(
        [("--config", args.config), *(("log", p) for p in paths)],
        [("--out index", Path(args.out) / LOGS_FILE)],
    )
    check_output_dir(args.out, "fleet output")
    config_toml = None
    if args.config:  # validated here, sent to the workers as text (they may not see the file)
        name = json.dumps(str(args.config))  # a TOML basic string
        config_toml = f"_path = {name}\n" + load_config(args.config).to_toml()
    console = Console(stderr=True)
    from bench.pipeline.warmup import prepare

    # compiled here once, the local workers load it from the disk cache instead of each
    # compiling it on a first start
    prepare(lambda m: console.print(f"bench: {m}", highlight=False, soft_wrap=True))
    outcome = run_fleet(
        paths,
        args.out,
        workers=args.workers,
        scheduler=args.scheduler,
        config_toml=config_toml,
        console=console,
        progress=not args.quiet and console.is_terminal,
        smooth=args.smooth,
    )
    if not args.quiet:
        print_whole(fleet_table(outcome))
    for row in outcome.rows:
        error = row.get("error")
        if error:
            where = "" if str(error).startswith(row["path"]) else f"{row['path']}: "
            console.print(f"bench: warning: {where}{error}", highlight=False)
    rate = outcome.frames / outcome.wall_s if outcome.wall_s > 0 else 0.0
    console.print(
        f"bench: fleet of {len(outcome.rows)} logs on {outcome.workers} workers: "
        f"{outcome.replayed} replayed, {outcome.skipped} skipped (done before), "
        f"{outcome.failed} failed; {outcome.frames:,} frames in {outcome.wall_s:.1f} s "
        f"({rate / 1e3:,.0f} k frames/s); {args.out}/logs.parquet",
        highlight=False,
    )
    return 1 if outcome.failed else 0
