"""`bench calibrate LOG --out config.toml`: as-built mounting angles from a recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.errors import BenchError
from devices.paths import check_clashes, regular_file_problem, write_file

REFERENCE_HELP = (
    "what the recording is known to show: 'speed' (in motion, against SPEED_REF), 'level' "
    "(standstill on level track) or a tilt-table CSV of steps start_s,end_s,gradient_permil "
    "(board time from the first sample); default: speed if the log has SPEED_REF, else level"
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="estimate the as-built channel angles (and offsets) from a log; write a config",
        description="Fit the mounting angles (and the offsets the data determines) by least "
        "squares to a recording, report residual and uncertainties, and write a config that "
        "the other commands read with --config.",
    )
    p.add_argument("log", help="recording: .log (candump), .asc, .blf, .trc, .csv, .bin, .mcap")
    p.add_argument(
        "--reference", default=None, metavar="speed|level|TABLE.csv", help=REFERENCE_HELP
    )
    p.add_argument("--config", help="starting config (scales, g, ...); default: nominal values")
    p.add_argument("--out", required=True, metavar="CONFIG.toml", help="calibrated config to write")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.calibration import calibrate, read_table, record
    from bench.config import load_config
    from devices.formats import open_log

    check_clashes(
        [("log", args.log), ("--config", args.config), ("--reference table", args.reference)],
        [("--out", args.out)],
    )
    reference, table = args.reference, None
    if reference is not None and reference not in ("speed", "level"):
        if not reference.lower().endswith(".csv"):
            raise BenchError(
                f"--reference {reference!r}: expected speed, level or a .csv table of steps"
            )
        if why := regular_file_problem(reference):  # a FIFO is no table: reading it waits
            why = "table file not found" if why == "no such file" else f"cannot read it: {why}"
            raise BenchError(f"--reference {reference}: {why}")
        table = read_table(reference)
        reference = "table"
    config = load_config(args.config)
    print(f"bench: starting from {config.announcement()}")
    source = open_log(args.log)
    try:
        rec = record(source.batches(), config)
    finally:
        source.close()
    if reference is None:
        reference = "speed" if rec.has_speed_ref else "level"
    fit = calibrate(rec, config, reference, table)
    print(f"{args.log}: {fit.report()}")
    out = Path(args.out)
    try:
        header = [f"bench calibrate {args.log} --reference {args.reference or reference}"]
        header += fit.report().splitlines()
        write_file(out, "".join(f"# {line}\n" for line in header) + fit.config.to_toml())
    except OSError as exc:
        raise BenchError(f"cannot write {out}: {exc.strerror or exc}") from None
    print(f"wrote {out}")
    return 0
