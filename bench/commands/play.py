"""`bench play`: a recorded log's frames onto a CAN bus at their recorded timing.

The HIL use: a recorded board's traffic replayed into the unit that consumes it (or into a
second bench). Any log the bench reads, its MCAP included; python-can's MessageSync paces it
(:mod:`bench.replay.bus_player`). Ctrl-C, SIGTERM and SIGHUP stop it at once with the count
so far, and exit 128 + the signal's number (130, 143, 129), as a shell expects.
"""

from __future__ import annotations

import argparse
import shutil
import signal
import sys
import threading
from types import FrameType
from typing import Any

from bench.commands.argtypes import OFFSET, RATE, SECONDS
from bench.errors import BenchError
from devices.cli_args import add_interface_argument


class Stopped(Exception):
    """Raised by the signal handler on the playing thread: play ends where it is."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "play",
        help="put a recorded log's frames onto a CAN bus at their recorded timing",
        description=(
            "Play the frames of a log (.log .asc .blf .trc .csv .mcap) onto a python-can bus "
            "at their recorded timing, like python-can's can.player, for a unit that consumes "
            "the board's traffic. Error frames are not sent. See docs/DEVICES.md."
        ),
    )
    p.add_argument("log", metavar="LOG", help="the log to play")
    add_interface_argument(p, "python-can interface (e.g. socketcan, pcan, virtual)")
    p.add_argument("-c", "--channel", help="python-can channel (e.g. vcan0, can0)")
    p.add_argument("-b", "--bitrate", type=int, help="bit rate, where the interface needs one")
    p.add_argument(
        "--rate",
        type=RATE,
        default=1.0,
        metavar="FACTOR",
        help="speed factor: 2 plays twice as fast as recorded, 0.5 at half speed (default 1)",
    )
    p.add_argument("--loop", action="store_true", help="play the log again and again")
    p.add_argument(
        "--ids",
        metavar="IDS",
        help="only these CAN IDs, in hex as candump prints them: 101,102 or 100-103",
    )
    p.add_argument(
        "--skip-to",
        type=OFFSET,
        default=0.0,
        metavar="S",
        help="start S seconds into the log (after its first frame)",
    )
    p.add_argument("--quiet", "-q", action="store_true", help="no status line")
    p.add_argument(
        "--status-every",
        type=SECONDS,
        metavar="S",
        help="print the status line every S seconds (default 0.25 on a terminal, else 5)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bench.replay.bus_player import BusPlayer, Selection, count_log, parse_ids
    from devices.bus import describe_config, open_bus, resolve_bus_config

    try:
        ids = parse_ids(args.ids) if args.ids is not None else None
    except ValueError as exc:
        raise BenchError(f"--ids: {exc}") from None
    selection = Selection(ids=ids, skip_to_s=args.skip_to)
    path = Path(args.log)
    config = resolve_bus_config(args.interface, args.channel, args.bitrate)  # before the count
    counts = count_log(path, selection)
    if not counts.in_log:
        raise BenchError(f"{path}: no frames to play")
    if not counts.selected:
        raise BenchError(
            f"{path}: none of its {counts.in_log} frames is selected ({_left(counts)})"
        )
    bus = open_bus(config)
    player = BusPlayer(path, bus, counts, selection, rate=args.rate, loop=args.loop)
    print(
        f"bench: playing {path} onto {describe_config(config)}: {counts.selected} of "
        f"{counts.in_log} frames, {counts.duration_s:.1f} s recorded, at {args.rate:g}x"
        f"{', looping' if args.loop else ''}; Ctrl-C stops",
        flush=True,
    )
    status = _Status(player, sys.stderr.isatty(), args.status_every, quiet=args.quiet)

    def stop(signum: int, frame: FrameType | None) -> None:
        player.interrupt = Stopped(signum)  # kept for the player, should the raise be lost
        raise player.interrupt

    old = {s: signal.signal(s, stop) for s in _SIGNALS}
    stopped: Stopped | None = None
    status.start()
    try:
        player.play()
    except (Stopped, KeyboardInterrupt) as exc:
        stopped = exc if isinstance(exc, Stopped) else Stopped(signal.SIGINT)
    finally:
        # deaf to repeats while closing: a second Ctrl-C must not cut the closing line
        for s in old:
            signal.signal(s, signal.SIG_IGN)
        status.stop()
        bus.shutdown()
    try:
        return _report(player, stopped)
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


_SIGNALS = [signal.SIGINT, signal.SIGTERM, *([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])]


def _left(counts: Any) -> str:
    parts = []
    if counts.before_skip:
        parts.append(f"{counts.before_skip} before --skip-to")
    if counts.by_ids:
        parts.append(f"{counts.by_ids} of other IDs")
    if counts.error_frames:
        parts.append(f"{counts.error_frames} error frames, not sent")
    return ", ".join(parts) or "none left out"


def counts_text(player: Any) -> str:
    """Frames sent against those in the log: the closing line's substance."""
    c = player.counts
    text = f"{player.sent} frames sent of {c.selected} selected ({c.in_log} in the log"
    left = _left(c)
    text += f"; {left})" if c.selected != c.in_log else ")"
    if player.loop:
        text += f", pass {player.passes}"
    text += f", {player.errors} send errors"
    if player.errors:
        text += f" (last: {player.last_error})"
    if c.problems:
        text += f", {c.problems} unreadable records in the log (not sent)"
    return text


def _report(player: Any, stopped: Stopped | None) -> int:
    if stopped is not None:
        print(
            f"bench: stopped ({stopped}) at {player.position_s:.1f} s: {counts_text(player)}",
            flush=True,
        )
        return 128 + stopped.signum
    print(f"bench: done: {counts_text(player)}", flush=True)
    if player.errors:
        print(f"bench: error: {player.errors} frames could not be sent", file=sys.stderr)
        return 1
    return 0


class _Status:
    """The one-line status, from a thread of its own (the playing thread may be asleep in
    a long recorded gap): every 0.25 s on a terminal, every 5 s otherwise."""

    def __init__(self, player: Any, tty: bool, every: float | None, *, quiet: bool) -> None:
        self.player = player
        self.tty = tty
        self.every = every if every is not None else (0.25 if tty else 5.0)
        self._done = threading.Event()
        self._thread = None if quiet else threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        if self._thread is not None:
            self._thread.start()

    def stop(self) -> None:
        self._done.set()
        if self._thread is not None:
            self._thread.join(2.0)
            if self.tty:
                self._write("")

    def line(self) -> str:
        p = self.player
        c = p.counts
        text = (
            f"{p.position_s:8.1f}/{c.duration_s:.1f} s  {p.sent} of {c.selected} frames sent"
            f" ({c.in_log} in the log)  errors {p.errors}"
        )
        return text + (f"  pass {p.passes}" if p.loop else "")

    def _run(self) -> None:
        while not self._done.wait(self.every):
            self._write(self.line())

    def _write(self, text: str) -> None:
        if self.tty:
            width = shutil.get_terminal_size((100, 20)).columns - 1
            sys.stderr.write("\r" + text[:width].ljust(width) + ("" if text else "\r"))
        else:
            sys.stderr.write(text + "\n")
        sys.stderr.flush()
