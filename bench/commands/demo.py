"""`bench demo`: the TUI on the in-process virtual board running the built-in demo scenario.

The quickest way to see the bench work: no hardware, no options. The board is calibrated
with the scenario's as-built values (as a real bench would be from its calibration sheet),
so what goes wrong on screen is the faults the scenario injects, not a calibration error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import devices
from bench.commands.argtypes import SPEED, add_lag_argument
from bench.config_choice import announce, live_config, scenario_config
from bench.defaults import log_folder
from bench.live.setup import add_log_arguments, check_live_paths
from bench.mcaplog.foxglove_stream import add_foxglove_arguments

__all__ = ["DEMO_SCENARIO", "register", "run", "scenario_config"]

DEMO_SCENARIO = Path(devices.__file__).resolve().parent / "scenarios" / "demo.toml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="the TUI on the built-in virtual board: a metro service, faults coming and going",
        description="Open the bench TUI on the in-process virtual board playing the demo "
        "scenario (9 min of a metro service over hills with faults coming and going), logging "
        "to logs/ like "
        "`bench run`. Keys: p pause display, r record, m mark, +/- tolerance, q quit.",
    )
    p.add_argument(
        "--scenario",
        metavar="SCENARIO",
        default=str(DEMO_SCENARIO),
        help="another scenario file or built-in name (default: the demo)",
    )
    p.add_argument(
        "--speed", type=SPEED, default=1.0, help="emulator time factor (default 1 = real time)"
    )
    p.add_argument(
        "--config", help="calibration config (TOML); default: the scenario board's calibration"
    )
    add_log_arguments(p)
    add_foxglove_arguments(p)
    add_lag_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from bench.commands.tui import show
    from bench.engine.client import start_engine
    from bench.engine.plans import EmulatorPlan, cli_values
    from devices.emulator.scenario import resolve_scenario_path

    check_live_paths(args)
    path = resolve_scenario_path(args.scenario)
    config = live_config(args.config, path)
    log_dir = Path(args.mcap).parent if args.mcap else log_folder()
    plan = EmulatorPlan(
        config=config,
        args=cli_values(args),
        log_dir=log_dir,
        scenario=path,
        speed=args.speed,
        lag_s=args.lag,
    )
    announce(config, lambda m: print(f"bench: {m}", file=sys.stderr))  # before the screen
    session = start_engine(plan, warn=lambda m: print(f"bench: {m}", file=sys.stderr))
    return show(session, notices=[config.announcement()])
