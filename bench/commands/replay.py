"""`bench replay INPUT`: re-run fusion over a recorded log, write the per-sample CSV/Parquet."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.config import Config
from bench.config_choice import replay_config, replay_hint
from bench.errors import BenchError
from bench.sinks.paths import check_output_file
from devices.paths import check_clashes

if TYPE_CHECKING:
    from rich.console import Console

MAX_NOTICES = 20
"""Warnings printed one by one; the rest are counted (a log of noise must not flood the screen)."""


class _LazyConsole:
    """The run's rich console on stderr, made (and rich imported) when something is shown:
    a quiet replay without warnings never imports rich (about 45 ms of its start)."""

    def __init__(self) -> None:
        self._console: Console | None = None

    def __call__(self) -> Console:
        if self._console is None:
            from rich.console import Console

            self._console = Console(stderr=True)
        return self._console


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help="re-run fusion over a log (.log .asc .blf .trc .csv .bin .mcap) and write a CSV",
        description="Replay a log through the live pipeline; one CSV row per sample.",
    )
    p.add_argument(
        "input", help="log file: .log (candump), .asc, .blf, .trc, .csv, .bin (UART), .mcap"
    )
    p.add_argument(
        "--config",
        help="calibration config (TOML); default: the one recorded in an MCAP log, "
        "else the ICD's nominal values (for an emulator .log: the sheet `bench emulate "
        "--calibration-out` wrote)",
    )
    p.add_argument(
        "--csv", metavar="OUT", help="write the per-sample results here ('-' for stdout)"
    )
    p.add_argument(
        "--parquet",
        metavar="OUT",
        help="write the per-sample results as Parquet (zstd; units and calibration in the schema)",
    )
    p.add_argument(
        "--mcap",
        metavar="OUT",
        help="write the replay as an MCAP log (frames, samples, results, events); with "
        "--smooth its results carry the smoother's columns",
    )
    p.add_argument(
        "--compare",
        action="store_true",
        help="(MCAP input) would this run have passed with --config? One table: validity "
        "and vote failures before (recorded calibration) and after (--config) and, with "
        "--plan, each check's verdict both ways; exit 1 when the results differ",
    )
    p.add_argument(
        "--plan",
        metavar="PLAN",
        help="with --compare: judge the acceptance plan's checks (file or shipped name) on "
        "both sides",
    )
    p.add_argument(
        "--smooth",
        action="store_true",
        help="also write gradient_smoothed_permil and its sigma: the explicit model's RTS "
        "smoother over the whole log (reads the log twice); the other columns are unchanged",
    )
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar or summary")
    p.set_defaults(func=run)


def one_blas_thread() -> None:
    """A replay does no linear algebra large enough for OpenBLAS's threads (the estimator's
    kernels are numba's): with one thread numpy's import starts no pool of them (about 80 ms
    of CPU, which a loaded machine takes from the pipeline). Only before numpy is imported,
    and an operator's own OPENBLAS_NUM_THREADS stands."""
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def run(args: argparse.Namespace) -> int:
    one_blas_thread()
    from bench.records.columns import RESULTS
    from bench.sinks.tables import abort_all, csv_sink, parquet_sink, results_metadata
    from devices.formats import open_log

    _stderr = _LazyConsole()
    check_clashes(
        [("input log", args.input), ("--config", args.config), ("--plan", args.plan)],
        [("--csv", args.csv), ("--parquet", args.parquet), ("--mcap", args.mcap)],
    )
    if args.csv:
        check_output_file(args.csv, "CSV")
    if args.parquet:
        check_output_file(args.parquet, "Parquet file")
    if args.plan and not args.compare:
        raise BenchError("--plan judges a plan's checks both ways: it needs --compare")
    if args.smooth and args.compare:
        raise BenchError("--compare judges the filtered results: it does not take --smooth")
    if args.compare and not str(args.input).lower().endswith(".mcap"):
        raise BenchError("--compare needs an .mcap input (only MCAP logs hold recorded results)")
    plan = None
    if args.plan:
        from bench.acceptance.plan import load_plan

        plan = load_plan(args.plan)
    if str(args.input).lower().endswith(".mcap"):
        from devices.paths import check_readable

        check_readable(Path(args.input))  # before its recorded config is read: not a FIFO
    config = replay_config(args.config, args.input)
    if args.compare:
        _check_recorded_results(args.input)
    from bench.pipeline.warmup import prepare

    smoothed = None
    if args.smooth:
        smoothed = _smoothing_pass(args.input, config)
    source = open_log(args.input)
    sinks = []
    layout = RESULTS
    if args.smooth:
        from bench.replay.model_columns import LAYOUT

        layout = LAYOUT
    try:
        if args.csv:
            sinks.append(csv_sink(args.csv, layout=layout))
        if args.parquet:
            meta = results_metadata(config, args.input)
            sinks.append(parquet_sink(args.parquet, meta, layout=layout))
        mcap = None
        if args.mcap:
            from bench.replay.mcap_out import ReplayMcap

            mcap = ReplayMcap(args.mcap, config, args.input, smoothed is not None)
    except BaseException:
        abort_all(sinks)
        source.close()
        raise
    from bench.replay.run import no_frames, replay  # the pipeline: after the files are open

    def first_start() -> None:  # the replay's first frames are decoded meanwhile
        prepare(lambda m: print(f"bench: {m}", file=sys.stderr))  # a first start says so

    total = source.size_bytes()
    show = not args.quiet and total > 2_000_000 and _stderr().is_terminal
    collected = None
    if args.compare:  # this replay is the comparison's "after" side: keep its events too
        from bench.acceptance.runner import Collector

        collected = Collector()
    feed: list[Any] = [*sinks, collected] if collected is not None else list(sinks)
    feed += [mcap.sink] if mcap is not None else []
    joined = None
    if smoothed is not None:
        from bench.replay.smooth import SmoothedSinks

        joined = SmoothedSinks(sinks, smoothed, [mcap.sink] if mcap is not None else [])
        feed = [joined]
    try:
        if show:
            from rich.progress import (
                BarColumn,
                DownloadColumn,
                Progress,
                TimeRemainingColumn,
                TransferSpeedColumn,
            )

            columns = (
                *Progress.get_default_columns()[:1],
                BarColumn(),
                DownloadColumn(),
                TransferSpeedColumn(),
                TimeRemainingColumn(),
            )
            with Progress(*columns, console=_stderr(), transient=True) as progress:
                task = progress.add_task(f"replay {args.input}", total=total)
                outcome = replay(
                    source,
                    config,
                    feed,
                    collect=False,
                    on_progress=lambda pos: progress.update(task, completed=pos),
                    before_estimator=first_start,
                )
        else:
            outcome = replay(source, config, feed, collect=False, before_estimator=first_start)
        if not outcome.pipeline.stats.frames:
            raise no_frames(args.input, outcome.notices)
        if joined is not None:
            joined.check_complete()
    except BaseException:
        abort_all(sinks)  # the first failure is the one to tell; no output is left
        if mcap is not None:
            mcap.abort()
        raise
    else:
        from bench.replay.mcap_out import close_outputs

        close_outputs(sinks, mcap)  # raises a write failure as a one-line error
    finally:
        source.close()
    if not args.quiet:  # plain lines: a console width must not break them
        print(f"bench: {config.announcement()}", file=sys.stderr)
        if smoothed is not None:
            from bench.replay.model_columns import describe_estimates

            print(f"bench: {smoothed.describe()}", file=sys.stderr)
            if line := describe_estimates(smoothed):
                print(f"bench: {line}", file=sys.stderr)
        hint = replay_hint(config, args.input)
        if hint:
            print(f"bench: {hint}", file=sys.stderr)
    shown = outcome.notices[:MAX_NOTICES]
    if shown:
        from rich.markup import escape
    for notice in shown:
        _stderr().print(f"[yellow]warning:[/] {escape(notice)}", soft_wrap=True)  # one line each
    if len(outcome.notices) > len(shown):
        rest = len(outcome.notices) - len(shown)
        _stderr().print(f"[yellow]warning:[/] ... and {rest} more (see the summary counts)")
    if not args.quiet:
        from bench.sinks.summary import print_summary

        print_summary(outcome.pipeline.stats, title=f"replay of {args.input}", console=_stderr())
    if collected is not None:
        from rich.console import Console

        from bench.acceptance.whatif import Side

        label = "after (--config)" if args.config else "after (recomputed)"
        after = Side(label, config, collected.results(), collected.events(), outcome.pipeline.stats)
        return _compare(args, after, plan, Console())
    return 0


def _smoothing_pass(path: str, config: Config) -> Any:
    """The smoother's reading of the log (bench.replay.smooth), before the replay proper."""
    from bench.replay.smooth import smoothing_pass
    from devices.formats import open_log

    source = open_log(path)
    try:
        return smoothing_pass(source, config)
    finally:
        source.close()


def _check_recorded_results(path: str) -> None:
    """--compare needs the results the run recorded: say so before replaying."""
    from bench.mcaplog import schemas as S
    from bench.mcaplog.reader import McapLog

    with McapLog(path) as lg:
        if not lg.message_counts().get(S.RESULT_TOPIC, 0):
            raise BenchError(
                f"{path}: no recorded results to compare with (an emulator's or another "
                "writer's log holds only frames): replay it without --compare"
            )


def _compare(args: argparse.Namespace, after: Any, plan: Any, console: Console) -> int:
    """Before (the recorded calibration) against after (this replay's) in one table. The
    replay just done is the after side; before is replayed only when its calibration
    differs (the same calibration gives the same results: one replay serves both)."""
    import dataclasses

    from bench.acceptance.whatif import comparison_table, measure, replay_side, same_calibration
    from bench.mcaplog.compare import compare_results
    from bench.mcaplog.recorded import read_results, recorded_config

    recorded = recorded_config(args.input) or Config()
    if same_calibration(recorded, after.config):
        before = dataclasses.replace(after, label="before (recorded)", config=recorded)
    else:
        before = replay_side(args.input, recorded, "before (recorded)")
    note = measure(plan, [before, after], args.input) if plan is not None else None
    report = compare_results(read_results(args.input), after.results)
    print(f"before: {recorded.describe()}")
    print(f"after:  {after.config.describe()}")
    console.print(comparison_table(before, after, report.rows_differing, plan))
    if note:
        console.print(note, highlight=False, markup=False)
    if report.identical:
        line = f"compare: identical ({report.matched_rows} rows match the recording exactly)"
    else:
        line = (
            f"compare: DIFFERENT ({report.rows_differing} of {report.matched_rows} rows "
            f"differ from the recording)"
        )
    console.print(line, style="green" if report.identical else "bold red", highlight=False)
    return 0 if report.identical else 1
