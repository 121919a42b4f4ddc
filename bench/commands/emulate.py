"""`bench emulate`: run the virtual ACB-3 board from a scenario file.

Either into a file as fast as possible (--out: .log candump, .bin raw UART, .mcap), or in
real time on a CAN interface (--interface/--channel) or a pseudo-terminal (--pty), so the
bench (or anything else) can listen to it like to the real board.
"""

from __future__ import annotations

import argparse
import math
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bench.errors import BenchError
from devices.cli_args import add_interface_argument


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "emulate",
        help="run the virtual ACB-3 board from a scenario (file or real time)",
        description=(
            "Simulate the ACB-3 board from a scenario TOML and write the frames to a file "
            "(--out) or play them in real time on a CAN bus or a pseudo-terminal. "
            "See docs/EMULATOR.md and devices/scenarios/example.toml."
        ),
    )
    p.add_argument(
        "scenario",
        nargs="?",
        metavar="SCENARIO",
        help="scenario TOML file, or the name of a built-in scenario (see --list)",
    )
    p.add_argument(
        "--out",
        metavar="FILE",
        help="write the run to FILE as fast as possible: .log (candump), .bin (raw UART bytes, "
        "UART faults applied) or .mcap",
    )
    p.add_argument(
        "--truth",
        metavar="CSV",
        help="write the truth per sampling instant (time_s, counter, gradient_permil, "
        "accel_mps2, speed_mps, position_m)",
    )
    p.add_argument(
        "--calibration-out",
        metavar="TOML",
        help="write the board's calibration sheet as built (the bench config for replaying "
        "--out FILE: bench replay FILE --config TOML)",
    )
    add_interface_argument(p, "python-can interface to play on (e.g. socketcan)")
    p.add_argument("--channel", "-c", help="python-can channel to play on (e.g. vcan0)")
    p.add_argument("--bitrate", type=int, help="bit rate, where the interface needs one")
    p.add_argument(
        "--pty", action="store_true", help="play the UART byte stream on a new pseudo-terminal"
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        metavar="FACTOR",
        help="real-time factor (2 = twice as fast); default 1",
    )
    p.add_argument("--seed", type=int, help="override the scenario's seed")
    p.add_argument("--quiet", "-q", action="store_true", help="no status line")
    p.add_argument("--list", action="store_true", help="list the built-in scenarios and exit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from devices.emulator import builtin_scenarios, load_scenario, simulate, write_truth_csv

    if args.list:
        for name in builtin_scenarios():
            print(f"{name:<18} {load_scenario(name).description}")
        return 0
    if not args.scenario:
        raise BenchError("give a SCENARIO (a TOML file or a built-in name; --list shows them)")
    realtime = bool(args.interface or args.channel or args.pty)
    if args.out and realtime:
        raise BenchError(
            "--out writes a file as fast as possible; drop --interface/--channel/--pty"
        )
    if args.pty and (args.interface or args.channel):
        raise BenchError("choose one of --pty and --interface/--channel")
    if not (args.out or realtime or args.truth or args.calibration_out):
        raise BenchError(
            "nothing to do: give --out FILE, --interface/--channel, --pty, --truth "
            "or --calibration-out"
        )
    if not (math.isfinite(args.speed) and args.speed > 0):
        raise BenchError(f"--speed must be a positive number, got {args.speed!r}")
    from bench.live.setup import scenario_file
    from devices.paths import check_clashes

    check_clashes(
        [("scenario", scenario_file(args.scenario))],
        [("--out", args.out), ("--truth", args.truth), ("--calibration-out", args.calibration_out)],
    )

    sc = load_scenario(args.scenario)
    if args.seed is not None:
        if args.seed < 0:
            raise BenchError(f"--seed must be >= 0, got {args.seed}")
        sc = sc.with_changes(seed=args.seed)
    if args.calibration_out:
        _write_calibration(sc, args.calibration_out, args.scenario)
    if sc.second_board is not None:
        return _two_boards(args, sc, realtime)
    if not realtime:  # files only: the run goes to them chunk by chunk, in bounded memory
        lines, counts = _write_streamed(sc, args.out, args.truth)
        for line in lines:
            print(line)
        if args.out and not args.quiet:
            print(counts.summary())
            print(_calibration_note(sc, args.out, args.calibration_out))
        return 0
    sim = simulate(sc)
    if args.truth:
        write_truth_csv(args.truth, sim.truth)
        print(f"wrote truth of {len(sim.truth)} sampling instants to {args.truth}")
    return _play(args, sim)


def _two_boards(args: argparse.Namespace, sc: Any, realtime: bool) -> int:
    """A scenario with [second_board]: both boards on one bus (devices.emulator.two_boards),
    played on the CAN interface or written as one candump log; the truth is the train's."""
    from devices.emulator import write_truth_csv
    from devices.emulator.two_boards import board_b, simulate_bus
    from devices.writers import write_candump

    if args.pty:
        raise BenchError(
            "two boards ([second_board]) share a CAN bus: use --interface/--channel or "
            "--out FILE.log (a pty carries one board's UART)"
        )
    if args.out and Path(args.out).suffix.lower() != ".log":
        raise BenchError(
            f"two boards ([second_board]) are written as a candump .log, not {args.out}"
        )
    if args.calibration_out:
        path = Path(args.calibration_out)
        _write_calibration(board_b(sc), str(path.with_stem(path.stem + "-b")), args.scenario)
    run = simulate_bus(sc)
    if args.truth:
        write_truth_csv(args.truth, run.truth)
        print(f"wrote truth of {len(run.truth)} sampling instants to {args.truth}")
    if realtime:
        return _play(args, run)
    if args.out:
        try:
            write_candump(args.out, run.frames)
        except OSError as exc:
            raise BenchError(f"{args.out}: cannot write: {exc.strerror or exc}") from None
        print(f"wrote {len(run.frames)} frames of two boards to {args.out}")
        if not args.quiet:
            print(run.summary())
    return 0


def _write_streamed(sc: Any, out: str | None, truth: str | None) -> tuple[list[str], Any]:
    """The run into ``out`` and/or the truth CSV as it is computed; an MCAP records its
    board's calibration as built, so that `bench replay FILE.mcap` reproduces the run."""
    from bench.config_choice import scenario_config
    from devices.emulator.stream_out import write_streamed

    def mcap_writer(path: Path, chunks: Any, scenario: Any) -> dict[str, int]:
        from bench.mcaplog.emulation import write_emulation

        config = scenario_config(scenario)
        try:
            return write_emulation(
                path,
                chunks,
                scenario,
                scenario.path or None,
                config=config,
                metadata={"calibration": config.describe()},
            )
        except OSError as exc:
            raise BenchError(f"{path}: cannot write: {exc.strerror or exc}") from None

    return write_streamed(sc, out, truth, mcap_writer=mcap_writer)


def _calibration_note(sc: Any, out: str, sheet: str | None) -> str:
    from bench.config_choice import is_mcap, scenario_config

    config = scenario_config(sc)
    if is_mcap(out):
        return f"calibration recorded in the log: {config.describe()} ({config.angles_text()})"
    if sheet:
        return f"replay it with the sheet: bench replay {out} --config {sheet}"
    return (
        f"note: {out} holds no calibration (board as built: {config.angles_text()}); "
        "--calibration-out cal.toml writes the sheet for bench replay --config"
    )


def _write_calibration(sc: Any, out: str, given: str) -> None:
    """The board's calibration sheet as built: what a bench replaying its frames needs."""
    from bench.config_choice import scenario_config
    from devices.emulator import calibration_toml
    from devices.paths import write_file

    config = scenario_config(sc)
    header = (
        f"# calibration sheet of the virtual board as built: bench emulate {given}\n"
        "# use it to replay this board's frames: bench replay FILE --config THIS_FILE\n"
    )
    try:
        write_file(out, header + calibration_toml(sc))  # whole or not at all
    except OSError as exc:
        raise BenchError(f"{out}: cannot write: {exc.strerror or exc}") from None
    print(f"wrote the calibration sheet to {out} ({config.angles_text()})")


def _play(args: argparse.Namespace, sim: Any) -> int:
    from devices.cpu_placement import other_cpus
    from devices.emulator import CanPlayer, PtyPlayer

    # a board in a process of its own is not part of any bench's live path: it keeps off
    # the CPU a bench on this machine gives its live threads (BENCH_LIVE_CPU)
    cpus = other_cpus()
    if args.pty:
        player: Any = PtyPlayer(sim.uart_stream(), sim.t0, speed=args.speed, cpus=cpus)
        print(f"virtual board UART on {player.slave_path} (921600 8N1); Ctrl-C stops", flush=True)
        unit = "packets"
    else:
        from devices.bus import describe_config, open_bus, resolve_bus_config

        config = resolve_bus_config(args.interface, args.channel, args.bitrate)
        player = CanPlayer(sim, open_bus(config), speed=args.speed, own_bus=True, cpus=cpus)
        print(f"virtual board on {describe_config(config)}; Ctrl-C stops", flush=True)
        unit = "frames"
    live = sys.stderr.isatty() and not args.quiet
    player.start()
    try:
        while not player.wait(0.25):
            if live:
                _status(_status_line(player, sim, unit))
    except KeyboardInterrupt:
        player.stop()
        if live:
            _status("")
        print(f"stopped at {player.progress_s:.1f} s: {_counts(player, unit)}", flush=True)
        return 130
    finally:
        player.stop()
    if live:
        _status("")
    if player.error is not None:
        raise BenchError(f"virtual board stopped: {player.error}")
    print(f"done: {_counts(player, unit)}", flush=True)
    return 0


def _counts(player: Any, unit: str) -> str:
    text = f"{player.frames_sent} of {player.items_total} {unit} sent"
    if getattr(player, "errors", 0):
        text += f", {player.errors} send errors (last: {player.last_error})"
    if getattr(player, "bytes_discarded", 0):
        text += f", {player.bytes_discarded} bytes discarded (no reader)"
    return text


def _status_line(player: Any, sim: Any, unit: str) -> str:
    sc = sim.scenario
    now = min(player.progress_s, sc.duration_s)
    k = min(int(np.searchsorted(sim.truth["time_s"] - sim.t0, now)), len(sim.truth) - 1)
    row = sim.truth[k]
    active = [
        f"{'ch' if isinstance(f.target, int) else ''}{f.target} {f.kind}"
        for f in sc.faults
        if f.start_s <= now < f.end_s
    ]
    line = (
        f"{now:7.1f}/{sc.duration_s:g} s  {player.frames_sent} {unit}"
        f"  v {row['speed_mps']:6.2f} m/s  grade {row['gradient_permil']:+7.2f} permil"
    )
    if getattr(player, "errors", 0):
        line += f"  {player.errors} errors"
    if active:
        line += "  faults: " + ", ".join(active)
    return line


def _status(text: str) -> None:
    width = shutil.get_terminal_size((100, 20)).columns - 1
    sys.stderr.write("\r" + text[:width].ljust(width) + ("" if text else "\r"))
    sys.stderr.flush()
