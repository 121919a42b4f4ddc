"""``bench log info FILE`` and ``bench log export FILE --csv OUT | --parquet OUT | --candump OUT``.

info: duration, frames per ID and outcome, link errors, vote-failure and invalid spans,
metadata (docs/MCAP.md). export --csv/--parquet: the recorded results as the replay's CSV or
Parquet file (or, with --recompute or when the file holds no results, fusion re-run on the
raw frames); export --candump: the raw frames as a candump -L text log.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from bench.sinks.paths import check_output_file, write_error
from devices.paths import check_clashes, staged


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "log",
        help="inspect and convert MCAP run logs",
        description="Inspect and convert the bench's MCAP run logs (docs/MCAP.md).",
    )
    sub = p.add_subparsers(dest="log_command", metavar="ACTION", required=True)

    info = sub.add_parser(
        "info", help="what a log holds: duration, frames per ID, errors, spans, metadata"
    )
    info.add_argument("file", type=Path, help="an MCAP file written by the bench")
    info.add_argument("--json", action="store_true", help="print the report as JSON")
    info.add_argument("--verify", action="store_true", help="also check every CRC in the file")
    info.add_argument(
        "--spans", type=int, default=20, metavar="N", help="list at most N spans of each kind"
    )
    info.set_defaults(func=run_info)

    exp = sub.add_parser(
        "export", help="convert a log to the replay CSV, Parquet or a candump text log"
    )
    exp.add_argument("file", type=Path, help="an MCAP file written by the bench")
    out = exp.add_mutually_exclusive_group(required=True)
    out.add_argument("--csv", metavar="OUT", help="results as the replay CSV ('-' = stdout)")
    out.add_argument(
        "--parquet", metavar="OUT", help="results as the replay's Parquet file (zstd, units)"
    )
    out.add_argument(
        "--candump", metavar="OUT", help="raw frames as candump -L text ('-' = stdout)"
    )
    exp.add_argument(
        "--recompute",
        action="store_true",
        help="with --csv/--parquet: re-run fusion on the raw frames, not the recorded results",
    )
    exp.add_argument(
        "--config", type=Path, help="with --recompute: config to use (default: the recorded one)"
    )
    exp.set_defaults(func=run_export)


def run_info(args: argparse.Namespace) -> int:
    from bench.mcaplog.info import format_info, log_info

    info = log_info(args.file, verify=args.verify, max_spans=max(0, args.spans))
    if args.json:
        print(json.dumps(info, indent=1, default=str))
    else:
        print(format_info(info))
    if info["truncated"]:
        print(
            f"bench: warning: {info['warnings'][0] if info['warnings'] else 'truncated file'}",
            file=sys.stderr,
        )
    bench_topics = {t for t in info["topics"] if t.startswith(_OUR_TOPIC_PREFIXES)}
    if info["topics"] and not bench_topics:
        print(
            f"bench: error: {args.file}: no bench topics in this MCAP file (expected "
            f"/can/frames, /bench/...; it holds {', '.join(sorted(info['topics'])[:6])})",
            file=sys.stderr,
        )
        return 2
    return 1 if args.verify and info.get("crc_problems") else 0


_OUR_TOPIC_PREFIXES = ("/can/", "/uart/", "/source/", "/bench/", "/emulator/")


def _export_candump(frames: np.ndarray, target: str) -> tuple[int, int]:
    """The frames as candump text into ``target`` (``-``: stdout), whole or not at all."""
    if target == "-":
        written = write_candump(frames, sys.stdout)
        sys.stdout.flush()
        return written
    try:
        with staged(target) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
            return write_candump(frames, fh)
    except OSError as exc:
        raise write_error(target, exc) from None


def _refuse_nothing_to_export(lg: Any, frames_only: bool) -> None:
    """A log without a single frame (nor, for results, recorded results) is an error, as
    in ``bench replay``: an empty export is no export (it exited 0 with a header-only
    file). Nothing has been written yet."""
    from bench.mcaplog import schemas as S
    from bench.replay.run import no_frames

    counts = lg.message_counts()
    if counts.get(S.FRAME_TOPIC, 0) or (not frames_only and counts.get(S.RESULT_TOPIC, 0)):
        return
    raise no_frames(lg.path, [f"warning: {w}" for w in dict.fromkeys(lg.warnings)])


def run_export(args: argparse.Namespace) -> int:
    from bench.mcaplog.reader import McapLog

    target = args.candump or args.csv or args.parquet
    what = "candump log" if args.candump else "CSV" if args.csv else "Parquet file"
    flag = "--candump" if args.candump else "--csv" if args.csv else "--parquet"
    check_clashes([("input log", args.file), ("--config", args.config)], [(flag, target)])
    check_output_file(target, what)  # before reading anything
    with McapLog(args.file) as lg:
        _refuse_nothing_to_export(lg, frames_only=bool(args.candump or args.recompute))
        for warning in dict.fromkeys(lg.warnings):
            print(f"bench: warning: {warning}", file=sys.stderr)
        if args.candump:
            frames, errors, _ = lg.read_frames()
            written, no_time = _export_candump(frames, args.candump)
            print(f"bench: exported {written} frames to {args.candump}", file=sys.stderr)
            if no_time:
                print(
                    f"bench: warning: {no_time} frames had no receive time (written as 0.000000)",
                    file=sys.stderr,
                )
            if errors:
                print(
                    f"bench: note: {len(errors)} UART link errors have no candump form "
                    "(not exported)",
                    file=sys.stderr,
                )
            return 0
        rows = export_results(
            lg, target, parquet=bool(args.parquet), recompute=args.recompute,
            config_path=args.config,
        )  # fmt: skip
        print(f"bench: exported {rows} result rows to {target}", file=sys.stderr)
    return 0


def write_candump(frames: np.ndarray, fh: TextIO) -> tuple[int, int]:
    """candump -L lines: ``(t) can0 ID#DATA``; UART frames on interface ``uart0``,
    extended IDs with 8 hex digits, RTR as ``ID#R``, CAN FD as ``ID##0DATA``."""
    from protocol.records import FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, FLAG_UART

    lines = []
    no_time = 0
    hexdata = frames["data"].tobytes().hex().upper()  # 16 hex digits per frame
    for i, (t, cid, dlc, flags) in enumerate(
        zip(
            frames["t"].tolist(),
            frames["id"].tolist(),
            frames["dlc"].tolist(),
            frames["flags"].tolist(),
            strict=True,
        )
    ):
        data = hexdata[16 * i : 16 * i + 16]
        if not math.isfinite(t):
            no_time += 1
            t = 0.0
        iface = "uart0" if flags & FLAG_UART else "can0"
        ident = f"{cid:08X}" if flags & FLAG_EXTENDED or cid > 0x7FF else f"{cid:03X}"
        n = min(dlc, 8)
        if flags & FLAG_REMOTE:
            body = "#R"
        elif flags & FLAG_FD:
            body = "##0" + data[: 2 * n]
        else:
            body = "#" + data[: 2 * n]
            if 8 < dlc <= 15:
                body += f"_{dlc:X}"
        lines.append(f"({t:.6f}) {iface} {ident}{body}\n")
    fh.write("".join(lines))
    return len(lines), no_time


def export_results(
    lg: Any,
    target: str,
    *,
    parquet: bool = False,
    recompute: bool = False,
    config_path: Path | None = None,
) -> int:
    """Write the replay's CSV or Parquet file: recorded results, or fusion recomputed from the
    raw frames. Returns the rows written; a write failure is a one-line BenchError."""
    from bench.config import load_config
    from bench.mcaplog.recorded import read_results, recorded_config
    from bench.pipeline.steps import Pipeline
    from bench.sinks.tables import abort_all, csv_sink, parquet_sink, results_metadata

    config = load_config(config_path) if config_path else (recorded_config(lg) or load_config(None))
    from bench.records.columns import RESULTS

    layout = RESULTS
    results = None if recompute else read_results(lg)
    if results is not None and len(results):
        from bench.replay.model_columns import LAYOUT, recorded_smoothed

        if (smoothed := recorded_smoothed(lg)) is not None:  # replay --smooth --mcap's
            results, layout = smoothed, LAYOUT
    if results is not None and not len(results):
        results = None
        print(
            "bench: note: no results recorded in this file; recomputing from the raw frames",
            file=sys.stderr,
        )
    if parquet:
        sink = parquet_sink(target, results_metadata(config, str(lg.path)), layout=layout)
    else:
        sink = csv_sink(target, layout=layout)
    try:
        if results is not None:
            sink.put(results)
        else:
            from bench.mcaplog.source import McapFrameSource
            from bench.pipeline.warmup import prepare

            print(f"bench: {config.announcement()}", file=sys.stderr)
            prepare(lambda m: print(f"bench: {m}", file=sys.stderr))
            pipe = Pipeline(config)
            source = McapFrameSource(lg.path)
            try:
                for batch in source.batches():
                    sink.put(pipe.process(batch).results)
                sink.put(pipe.finish().results)
            finally:
                source.close()
    except BaseException:
        abort_all([sink])  # the failure being raised is the one to tell; nothing is left
        raise
    sink.close()
    return sink.rows
