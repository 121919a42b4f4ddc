"""``bench log info FILE`` and ``bench log export FILE --csv OUT | --candump OUT``.

info: duration, frames per ID and outcome, link errors, vote-failure and invalid spans,
metadata (docs/MCAP.md). export --csv: the recorded results as the replay CSV (or, with
--recompute or when the file holds no results, fusion re-run on the raw frames);
export --candump: the raw frames as a candump -L text log.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from contextlib import ExitStack
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from bench.errors import BenchError


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

    exp = sub.add_parser("export", help="convert a log to the replay CSV or a candump text log")
    exp.add_argument("file", type=Path, help="an MCAP file written by the bench")
    out = exp.add_mutually_exclusive_group(required=True)
    out.add_argument("--csv", metavar="OUT", help="results as the replay CSV ('-' = stdout)")
    out.add_argument(
        "--candump", metavar="OUT", help="raw frames as candump -L text ('-' = stdout)"
    )
    exp.add_argument(
        "--recompute",
        action="store_true",
        help="with --csv: re-run fusion on the raw frames, not the recorded results",
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
    return 1 if args.verify and info.get("crc_problems") else 0


def _open_out(stack: ExitStack, target: str) -> TextIO:
    if target == "-":
        return sys.stdout
    try:
        return stack.enter_context(open(target, "w", newline="", encoding="utf-8"))
    except OSError as exc:
        raise BenchError(f"{target}: cannot write: {exc.strerror or exc}") from None


def run_export(args: argparse.Namespace) -> int:
    from bench.mcaplog.reader import McapLog

    with McapLog(args.file) as lg, ExitStack() as stack:
        if lg.truncated:
            print(f"bench: warning: {lg.truncation}", file=sys.stderr)
        if args.candump:
            fh = _open_out(stack, args.candump)
            frames, errors, _ = lg.read_frames()
            written, no_time = write_candump(frames, fh)
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
        fh = _open_out(stack, args.csv)
        rows = export_csv(lg, fh, recompute=args.recompute, config_path=args.config)
        print(f"bench: exported {rows} result rows to {args.csv}", file=sys.stderr)
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


def export_csv(
    lg: Any, fh: TextIO, *, recompute: bool = False, config_path: Path | None = None
) -> int:
    """Write the replay CSV: recorded results, or fusion recomputed from the raw frames."""
    from bench.config import load_config
    from bench.mcaplog.recorded import read_results, recorded_config
    from bench.mcaplog.source import McapFrameSource
    from bench.pipeline.steps import Pipeline
    from bench.records.results import CsvWriter

    writer = CsvWriter(fh)
    if not recompute:
        results = read_results(lg)
        if len(results):
            writer.write(results)
            writer.close()
            return writer.rows
        print(
            "bench: note: no results recorded in this file; recomputing from the raw frames",
            file=sys.stderr,
        )
    config = load_config(config_path) if config_path else (recorded_config(lg) or load_config(None))
    print(f"bench: {config.announcement()}", file=sys.stderr)
    pipe = Pipeline(config)
    source = McapFrameSource(lg.path)
    try:
        for batch in source.batches():
            writer.write(pipe.process(batch).results)
        writer.write(pipe.finish().results)
    finally:
        source.close()
    writer.close()
    return writer.rows
