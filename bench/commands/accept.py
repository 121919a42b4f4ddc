"""`bench accept PLAN --out DIR`: a headless acceptance run with a verdict and a report.

Exit code 0 pass, 1 fail, 2 error (the bench itself failed, or bad input), so CI and an
overnight script can act on it without parsing anything.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from bench.errors import BenchError
from bench.sinks.console import print_whole
from bench.sinks.paths import check_output_dir, describe_os_error

if TYPE_CHECKING:
    from bench.acceptance.outcome import RunOutcome
    from bench.acceptance.plan import Plan
    from bench.acceptance.runner import StopRequest
    from bench.acceptance.signoff import RunContext

_STYLE = {"pass": "green", "warn": "yellow", "fail": "red", "error": "magenta", "skip": "dim"}


def register(sub: argparse._SubParsersAction) -> None:
    from devices.cli_args import add_source_arguments

    p = sub.add_parser(
        "accept",
        help="acceptance run of a plan: verdict, junit.xml, record.json, report.html, run.mcap",
        description="Run an acceptance plan (bench/plans or a PLAN.toml) and judge every check. "
        "A plan with a scenario runs on the emulated board as fast as possible (or --realtime "
        "through the virtual board); with source options it runs against a real board, with "
        "operator steps. Exit code 0 pass, 1 fail, 2 error.",
    )
    p.add_argument("plan", nargs="?", help="plan file, or the name of a shipped plan")
    p.add_argument("--list", action="store_true", help="list the shipped plans and exit")
    p.add_argument("--out", metavar="DIR", help="output folder (created; files are replaced)")
    p.add_argument("--yes", "-y", action="store_true", help="answer every operator step 'ok'")
    p.add_argument(
        "--steps",
        metavar="FILE",
        help="answers to the operator steps (TOML [[answers]]: answer, reference_permil, note)",
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="play the plan's scenario through the in-process virtual board and the live path",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="X",
        help="virtual board speed for --realtime (default 1 = real time)",
    )
    p.add_argument("--no-plots", action="store_true", help="report.html without PNG plots")
    rec = p.add_argument_group(
        "for the record", "the unit, the station and the operator (record.json, junit.xml, report)"
    )
    rec.add_argument("--dut-serial", metavar="SN", help="serial number of the unit under test")
    rec.add_argument("--dut-firmware", metavar="VERSION", help="its firmware version")
    rec.add_argument("--dut-hardware", metavar="REV", help="its hardware revision")
    rec.add_argument(
        "--station", help="the test station (default: $BENCH_STATION or the host name)"
    )
    rec.add_argument(
        "--operator", help="who runs the test (default: $BENCH_OPERATOR or the login name)"
    )
    p.add_argument("--config", help="calibration config (TOML); default: the plan's board")
    add_source_arguments(p)
    p.add_argument(
        "--emulate",
        metavar="SCENARIO",
        help="live run against the virtual board playing SCENARIO (instead of a real board)",
    )
    p.set_defaults(func=run)


def run_context(args: argparse.Namespace, plan: Plan) -> RunContext:
    """The unit (the plan's, command-line values winning), the station and the operator."""
    from bench.acceptance.signoff import RunContext, default_operator, default_station
    from devices.tomlcheck import control_character

    station = args.station or default_station()
    operator = args.operator or default_operator()
    given = {
        "--dut-serial": args.dut_serial,
        "--dut-firmware": args.dut_firmware,
        "--dut-hardware": args.dut_hardware,
        "--station (or $BENCH_STATION)": station,
        "--operator (or $BENCH_OPERATOR)": operator,
    }
    for option, value in given.items():
        if value is not None and (bad := control_character(value)):
            raise BenchError(
                f"{option} {value!r}: control character {bad}: the record, the report and "
                "junit.xml take plain text"
            )
    dut = plan.dut.override(
        serial=args.dut_serial, firmware=args.dut_firmware, hardware=args.dut_hardware
    )
    return RunContext(dut=dut, station=station, operator=operator)


def list_table() -> Table:
    from bench.acceptance.plan import load_plan, shipped_plans

    table = Table(title="shipped acceptance plans (bench/plans)")
    table.add_column("plan", style="bold", no_wrap=True)
    table.add_column("expect", no_wrap=True)
    table.add_column("runs on")
    table.add_column("length", justify="right", no_wrap=True)
    table.add_column("title")
    for path in shipped_plans():
        plan = load_plan(path)
        sc = plan.scenario
        if plan.steps:
            runs = f"board, {len(plan.steps)} steps"
            if sc is not None:
                runs += " (rehearsal: emulator)"
        else:
            runs = "emulator" if sc is not None else "board"
        if sc is not None:
            runs += f" {plan.link.upper()} {sc.sample_rate_hz} Hz"
            length = f"{sc.duration_s:g} s"
        else:
            length = "-" if plan.duration_s is None else f"{plan.duration_s:g} s"
        style = "green" if plan.expect == "pass" else "red"
        table.add_row(plan.name, f"[{style}]{plan.expect}[/]", runs, length, plan.title)
    return table


def run(args: argparse.Namespace) -> int:
    from bench.acceptance.answers import load_answers
    from bench.acceptance.plan import load_plan
    from bench.acceptance.runner import Options, has_live_source, run_plan

    console = Console()
    if args.list:
        print_whole(list_table(), console=console)
        return 0
    if not args.plan:
        raise BenchError("give a PLAN (file or shipped name), or --list to see the shipped plans")
    if not args.out:
        raise BenchError("--out DIR is required: the verdict, report and run.mcap go there")
    if args.yes and args.steps:
        raise BenchError("--yes and --steps both answer the operator steps: give one")
    if args.realtime and has_live_source(args):
        raise BenchError("--realtime plays the plan's own scenario: drop the source options")
    if not args.speed > 0:
        raise BenchError(f"--speed must be > 0, got {args.speed!r}")
    plan = load_plan(args.plan)
    check_paths(args, plan)
    answers = load_answers(args.steps) if args.steps else None
    err = Console(stderr=True)
    opts = Options(
        out_dir=Path(args.out),
        realtime=args.realtime,
        speed=args.speed,
        yes=args.yes,
        answers=answers,
        config_path=args.config,
        live_args=args,
        say=lambda text: err.print(f"bench: {text}", highlight=False, soft_wrap=True),
        plots=not args.no_plots,
        context=run_context(args, plan),
    )
    check_output_dir(args.out, "acceptance results")
    err.print(f"bench: acceptance plan {plan.name}: {plan.title}", highlight=False)
    from bench.pipeline.warmup import prepare

    prepare(lambda m: err.print(f"bench: {m}", highlight=False, soft_wrap=True))
    try:
        with stopped_by_signals(opts.stop):
            outcome = run_plan(plan, opts)
    except OSError as exc:  # a full disk or a vanished folder: an error, not a fail verdict
        where = exc.filename or args.out
        why = describe_os_error(exc)  # exit 2; a half-written junit.xml is not valid XML
        raise BenchError(f"{where}: cannot write the acceptance results: {why}") from None
    print_outcome(outcome, console)
    if outcome.error:
        print(f"bench: error: {outcome.error}", file=sys.stderr)
    return outcome.exit_code


@contextlib.contextmanager
def stopped_by_signals(request: StopRequest) -> Iterator[None]:
    """SIGTERM and SIGHUP end the run as Ctrl-C does (the records say so and are written);
    a second signal while they are written waits for them. The reason is kept in
    ``request`` too, for the run's loops to find if the raise was swallowed."""

    def stop(signum: int, frame: FrameType | None) -> None:
        for sig in old:
            signal.signal(sig, signal.SIG_IGN)
        request.reason = f"stopped by {signal.Signals(signum).name}"
        request.check()

    sigs = [signal.SIGTERM, *([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])]
    old = {sig: signal.signal(sig, stop) for sig in sigs}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def check_paths(args: argparse.Namespace, plan: Plan) -> None:
    """The files the run writes into --out against the files it reads, before it starts."""
    from bench.acceptance.plan import resolve_plan_path
    from bench.acceptance.report.write import output_files
    from bench.acceptance.runner import has_live_source
    from bench.live.setup import scenario_file
    from devices.paths import check_clashes

    writes_scenario = plan.scenario is not None and not has_live_source(args)
    check_clashes(
        [
            ("plan", resolve_plan_path(args.plan)),
            ("plan's scenario", plan.scenario_ref),
            ("--config", args.config),
            ("--steps", args.steps),
            ("--emulate scenario", scenario_file(args.emulate)),
        ],
        [("--out", p) for p in output_files(Path(args.out), scenario=writes_scenario)],
    )


def result_table(outcome: RunOutcome) -> Table:
    from bench.acceptance.expectation import status_of
    from bench.acceptance.report.measured import measured_text
    from bench.acceptance.report.text import format_limits

    table = Table(title=f"acceptance {outcome.plan.name}")
    table.add_column("check", style="bold")
    table.add_column("measured", justify="right", no_wrap=True)
    table.add_column("limits")
    table.add_column("verdict", no_wrap=True)
    for m in outcome.measurements:
        verdict = f"[{_STYLE[m.verdict]}]{m.verdict.upper()}[/]"
        status = status_of(m)
        if status == "as designed":
            verdict += " [green](as designed)[/]"
        elif status == "not as designed":
            verdict += " [bold red](expected fail)[/]"
        elif m.expect is not None:
            verdict += f" [dim](expected {m.expect})[/]"
        table.add_row(m.name, measured_text(m), format_limits(m), verdict)
    return table


def print_outcome(outcome: RunOutcome, console: Console) -> None:
    """The table, then one line per check that did not pass: which one and by how much."""
    from bench.acceptance.expectation import expectation_text, plan_line, status_of

    print_whole(result_table(outcome), console=console)
    for m in outcome.measurements:
        if m.verdict != "pass":
            style = _STYLE[m.verdict]
            console.print(f"[{style}]{m.verdict.upper()}[/] {m.name}: {m.detail}", highlight=False)
        if status_of(m) in ("as designed", "not as designed"):
            console.print(f"  {m.name}: {expectation_text(m)}", highlight=False, markup=False)
    res = outcome.result
    line = plan_line(outcome.plan.name, outcome.plan.expect, outcome.measurements, res)
    console.print(
        f"[bold {_STYLE[res]}]{res.upper()}[/] {escape(_tail(line, outcome.plan.name, res))} "
        f"in {outcome.wall_s:.1f} s; report: "
        f"{outcome.files.get('report', outcome.out_dir / 'report.html')}",
        highlight=False,
    )


def _tail(line: str, name: str, res: str) -> str:
    """``plan NAME (why)`` from plan_line's ``plan NAME: RESULT (why)``."""
    return f"plan {name}" + line.removeprefix(f"plan {name}: {res.upper()}")
