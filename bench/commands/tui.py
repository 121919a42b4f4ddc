"""`bench tui`: the live bench screen (bus, serial, in-process emulator) or a log replayed in it."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.commands.argtypes import add_lag_argument
from bench.config import Config
from bench.config_choice import announce, live_config, replay_config, replay_hint
from bench.defaults import log_folder
from bench.errors import BenchError
from bench.live.setup import add_live_arguments, check_live_paths

if TYPE_CHECKING:
    from bench.live.view import SessionLike

SPEED_CHOICES = {"1": 1.0, "1x": 1.0, "10": 10.0, "10x": 10.0, "max": None}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "tui",
        help="live screen: per-pair values, votes, gradient plot, board, events, recording",
        description="Watch fusion sample by sample on a live source, logging to MCAP "
        "(r starts/stops a recording, m marks, +/- tolerance, p pauses the display, q quits "
        "and finishes the log). With --replay FILE, play a recorded log in the same screen. "
        "See docs/TUI.md.",
    )
    add_live_arguments(p)
    add_lag_argument(p)
    g = p.add_argument_group("replay")
    g.add_argument(
        "--replay",
        metavar="FILE",
        help="replay a log (.log .asc .blf .trc .csv .bin .mcap) instead of a live source; "
        "not recorded unless --mcap is given",
    )
    g.add_argument(
        "--speed",
        choices=sorted(SPEED_CHOICES),
        default="1",
        help="replay speed: 1, 10 or max (default 1; s cycles it in the TUI)",
    )
    g.add_argument("--paused", action="store_true", help="start the replay paused (space plays)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_live_paths(args)
    if args.replay:
        config = replay_config(args.config, args.replay)
    else:
        config = live_config(args.config, args.emulate)
    log_dir = Path(args.mcap).parent if args.mcap else log_folder()
    say = lambda m: print(f"bench: {m}", file=sys.stderr)  # noqa: E731
    hint = replay_hint(config, args.replay) if args.replay else None
    if args.replay:  # in this process, at once: a log that cannot be read says only that
        session = run_replay(args, config, log_dir)
    announce(config, say)  # before the screen covers the terminal; the screen says it too
    if hint:
        say(hint)
    if not args.replay:  # the engine may take seconds to start: the line is up meanwhile
        session = run_live(args, config, log_dir)
    notices = [config.announcement(), *([hint] if hint else [])]
    if args.replay:
        return show(session, notices=notices, **replay_extras(args, config, log_dir))
    return show(session, notices=notices)


def show(session: SessionLike, **app_kwargs: Any) -> int:
    """The screen on a built session; the logs written are listed however it ends."""
    from bench.tui.run import run_tui

    try:
        return run_tui(session, **app_kwargs)
    finally:
        report(session)


def replay_extras(args: argparse.Namespace, config: Config, log_dir: Path) -> dict[str, Any]:
    """What the replay screen needs beyond the session: a factory for a new session on the
    same log (restart, seek back; never recording unless r is pressed), and the operator
    marks the log recorded (an MCAP file), for "run to the next mark"."""
    from bench.live.session import live_session, replay_setup

    def restart(paused: bool) -> SessionLike:
        speed = SPEED_CHOICES[args.speed]
        setup = replay_setup(args.replay, config, speed=speed, paused=paused)
        return live_session(setup, config, None, log_dir, lag_s=getattr(args, "lag", None))

    return {"restart": restart, "recorded_marks": recorded_marks(Path(args.replay))}


def recorded_marks(path: Path) -> list[tuple[float, str]]:
    """(log time, text) of the operator marks in an MCAP log; none for other formats or a
    file whose event record cannot be read (the replay itself reports that)."""
    if path.suffix.lower() != ".mcap":
        return []
    from bench.mcaplog.recorded import read_events
    from bench.records.events import EventKind

    try:
        events = read_events(path)
    except Exception:
        return []
    return [
        (float(e["t"]), str(e.get("text") or e.get("message", "mark")))
        for e in events
        if e.get("kind") == EventKind.MARK and isinstance(e.get("t"), int | float)
    ]


def run_live(args: argparse.Namespace, config: Config, log_dir: Path) -> SessionLike:
    """Source, pipeline and log in the engine process: the screen never holds up the run."""
    from bench.engine.client import start_engine
    from bench.engine.plans import LivePlan, cli_values

    plan = LivePlan(
        config=config, args=cli_values(args), log_dir=log_dir, lag_s=getattr(args, "lag", None)
    )
    return start_engine(plan, warn=lambda m: print(f"bench: {m}", file=sys.stderr))


def run_replay(args: argparse.Namespace, config: Config, log_dir: Path) -> SessionLike:
    """A log replayed in this process (no latency to keep there)."""
    from bench.live.session import live_session, replay_setup

    given = [
        opt
        for opt, value in (
            ("--emulate", args.emulate),
            ("--interface", args.interface),
            ("--channel", args.channel),
            ("--serial", args.serial),
        )
        if value
    ]
    if given:
        raise BenchError(f"--replay cannot be combined with {'/'.join(given)}")
    setup = replay_setup(args.replay, config, speed=SPEED_CHOICES[args.speed], paused=args.paused)
    first = None
    if args.mcap and not args.no_log:
        from bench.live.setup import start_recording

        first = start_recording(Path(args.mcap), setup, config)
    return live_session(setup, config, first, log_dir, lag_s=getattr(args, "lag", None))


def report(session: SessionLike) -> None:
    """After the screen closes: which logs were written, and any error the run hit (and what
    the engine process printed meanwhile, which would have scribbled over the screen)."""
    engine_report = getattr(session, "report", None)  # an engine session's, once stopped
    output = getattr(engine_report, "output", "")
    if output:
        sys.stderr.write(output if output.endswith("\n") else output + "\n")
    for path in session.recorder.files:
        print(f"bench: log written: {path}", file=sys.stderr)
    if session.error:
        print(f"bench: error: {session.error}", file=sys.stderr)
