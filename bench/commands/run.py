"""`bench run`: a headless live run with a one-line status, optional CSV, MCAP by default."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from types import FrameType
from typing import TYPE_CHECKING, Any, TextIO

from bench.commands.argtypes import SECONDS, add_lag_argument
from bench.config_choice import announce, live_config
from bench.live.setup import (
    LiveSetup,
    add_live_arguments,
    check_live_paths,
    open_live,
    open_recording,
)
from bench.live.view import Snapshot
from bench.mcaplog.foxglove_stream import open_stream
from bench.sinks.paths import check_output_file
from bench.sinks.summary import print_summary

if TYPE_CHECKING:
    from bench.live.runner import LiveRunner


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="live headless run: fuse frames as they arrive, log to MCAP",
        description="Acquire from a bus, serial port or the in-process virtual board; fuse live; "
        "print a status line; log every frame and result to MCAP.",
    )
    add_live_arguments(p)
    add_lag_argument(p)
    p.add_argument("--duration", type=SECONDS, metavar="S", help="stop after S seconds")
    p.add_argument("--csv", metavar="OUT", help="also write the per-sample results as CSV")
    p.add_argument("--quiet", "-q", action="store_true", help="no status line or summary")
    p.add_argument(
        "--status-every",
        type=SECONDS,
        metavar="S",
        help="print the status line every S seconds (default 0.5 on a terminal, else 5)",
    )
    p.set_defaults(func=run)


def status_line(s: Snapshot, elapsed: float) -> str:
    st = s.stats
    rate = s.frames_received / elapsed if elapsed > 0 else 0.0
    grad = "  ---  "
    if len(s.results):
        g = float(s.results["gradient"][-1])
        grad = f"{g:+7.2f}" if math.isfinite(g) else "invalid"
    valid = 100.0 * st.valid / st.samples if st.samples else 0.0
    gaps = sum(c.gaps for c in st.channels)
    kdrop = f" kdrop {st.socket_drops}" if st.socket_drops else ""
    if s.model is not None and s.model.dropped_samples:  # the live model's queue (--lag)
        kdrop += f" mdrop {s.model.dropped_samples}"
    rec = ""
    if s.recording is not None:
        rec = f" log {s.recording.frames_text()}"
    if s.output_errors:  # a secondary output (the CSV, the live stream) has failed
        rec += " CSV FAILED" if any("CSV" in e for e in s.output_errors) else " OUTPUT FAILED"
    return (
        f"{elapsed:7.1f}s {s.frames_received:9d} frames {rate:7.0f}/s  gradient {grad} permil  "
        f"valid {valid:5.1f}%  crc {st.crc_errors} gaps {gaps} link {st.link_errors} "
        f"drop {s.frames_dropped}{kdrop}{rec}"
    )


class _ClosedPipeSafe(io.TextIOBase):
    """stdout or stderr for a live run: when the reader goes away (``bench run | head -1``)
    what follows is dropped instead of a BrokenPipeError ending the recording early; the
    descriptor is pointed at /dev/null so the interpreter's last flush is quiet too."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream
        self.closed_pipe = False

    def write(self, text: str) -> int:
        if not self.closed_pipe:
            try:
                self._stream.write(text)
            except BrokenPipeError:
                self._gone()
        return len(text)

    def flush(self) -> None:
        if not self.closed_pipe:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._gone()

    def isatty(self) -> bool:
        return not self.closed_pipe and self._stream.isatty()

    def fileno(self) -> int:
        return self._stream.fileno()

    def _gone(self) -> None:
        self.closed_pipe = True
        with contextlib.suppress(OSError, ValueError):
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, self._stream.fileno())
            os.close(null)


@contextlib.contextmanager
def _closed_pipes_ignored() -> Iterator[None]:
    """A status pipe that closes does not stop a recording (see _ClosedPipeSafe)."""
    saved = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _ClosedPipeSafe(sys.stdout), _ClosedPipeSafe(sys.stderr)
    try:
        yield
    finally:
        sys.stdout, sys.stderr = saved


def run(args: argparse.Namespace) -> int:
    with _closed_pipes_ignored():
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    # from the first moment: a signal at any point ends the run with a finished log
    stop = threading.Event()
    signalled: list[int] = []

    def on_signal(signum: int, frame: FrameType | None) -> None:
        signalled.append(signum)  # a second signal while shutting down changes nothing
        stop.set()

    # SIGHUP (terminal closed, ssh dropped) like SIGTERM: its default would kill the run
    # before the summary, the CSV's last rows and the MCAP's summary section
    ends = [signal.SIGTERM, signal.SIGINT, *([signal.SIGHUP] if hasattr(signal, "SIGHUP") else [])]
    old_handlers = {sig: signal.signal(sig, on_signal) for sig in ends}
    from bench.live.runner import LiveRunner  # the pipeline only for this command (~0.5 s)

    with contextlib.ExitStack() as opening:  # unwound only when opening fails part way
        opening.callback(_restore_handlers, old_handlers, ignore=False)
        check_live_paths(args, ("--csv", args.csv))  # before a bus, a board or a file opens
        if args.csv:
            check_output_file(args.csv, "CSV")
        config = live_config(args.config, getattr(args, "emulate", None))
        setup = open_live(args)
        opening.callback(setup.close)
        sinks: list[Any] = []
        opening.callback(_close_sinks, sinks)

        def say(message: str) -> None:
            print(f"bench: {message}", file=sys.stderr)

        # the stream first, so that the log records its address (and a chosen port)
        stream = open_stream(args, config, say, setup.metadata)
        if stream is not None:
            sinks.append(stream)  # fed like the log: the processing thread only enqueues
        recording = open_recording(args, setup, config, warn=say)
        if not args.quiet:
            announce(config, say)
        if recording is not None:
            sinks.insert(0, recording)
            print(f"bench: logging to {recording.path}", file=sys.stderr)
        if args.csv:
            from bench.sinks.tables import csv_sink

            sinks.append(csv_sink(args.csv, live=True))
        opening.pop_all()  # all open: from here the run's own shutdown closes them
    from bench.pipeline.warmup import prepare

    prepare(lambda m: print(f"bench: {m}", file=sys.stderr))  # a first start: before the run
    runner = LiveRunner(
        setup.source, config, sinks, description=setup.description, lag_s=getattr(args, "lag", None)
    )
    runner.recording = recording
    start = time.monotonic()
    tty = sys.stderr.isatty()
    every = args.status_every if args.status_every is not None else (0.5 if tty else 5.0)
    last_print = 0.0
    runner.start()
    setup.start_board()
    try:
        while not stop.is_set():
            time.sleep(0.1)
            elapsed = time.monotonic() - start
            if args.duration is not None and elapsed >= args.duration:
                break
            if setup.emulator is not None and setup.emulator.done:
                time.sleep(0.2)  # let the last frames arrive
                break
            if not args.quiet and elapsed - last_print >= every:
                last_print = elapsed
                line = status_line(runner.snapshot(last=1), elapsed)
                end = "" if tty else "\n"
                print(("\r" + line) if tty else line, end=end, file=sys.stderr, flush=True)
    finally:
        if setup.emulator is not None:
            setup.emulator.stop()
        runner.stop()
        setup.close()
    try:
        return _report(args, runner, setup, recording, start, tty, stopped=bool(signalled))
    finally:
        # after a signal the process is on its way out: stay deaf to repeats, also through
        # interpreter teardown (which resets Python-level handlers, but not SIG_IGN)
        _restore_handlers(old_handlers, ignore=bool(signalled))


def _restore_handlers(old: dict[signal.Signals, Any], *, ignore: bool) -> None:
    """Put back the signal handlers the run replaced (``ignore``: SIG_IGN instead)."""
    for sig, handler in old.items():
        signal.signal(sig, signal.SIG_IGN if ignore else handler)


def _close_sinks(sinks: list[Any]) -> None:
    for sink in sinks:
        sink.close()


def _report(
    args: argparse.Namespace,
    runner: LiveRunner,
    setup: LiveSetup,
    recording: Any,
    start: float,
    tty: bool,
    stopped: bool = False,
) -> int:
    """The closing lines of a run; returns the exit code (``stopped``: by a signal, the
    operator's own end, so a run stopped before its first frame says so but is no error)."""
    if tty and not args.quiet:
        print(file=sys.stderr)
    snap = runner.snapshot(last=1)
    log_error = getattr(recording, "error", None) if recording is not None else None
    held = None
    if log_error:  # the writer's count is not what the file holds; the file is final now
        from bench.mcaplog.recorded import count_frames

        held = count_frames(recording.path)
        if snap.recording is not None:
            status = dataclasses.replace(snap.recording, error=log_error, file_frames=held)
            snap = dataclasses.replace(snap, recording=status)
    if not args.quiet:
        print(status_line(snap, time.monotonic() - start), file=sys.stderr)
        print_summary(runner.pipeline.stats, title=f"run on {setup.description}")
    if log_error:
        holds = "cannot be read back" if held is None else f"holds {held} frames"
        print(
            f"bench: error: the MCAP log failed: {log_error} (the file {holds}, "
            f"{runner.frames_received} received)",
            file=sys.stderr,
        )
    elif recording is not None and not args.quiet:
        print(f"bench: log written: {recording.path}", file=sys.stderr)
    if runner.error:
        print(f"bench: error: {runner.error}", file=sys.stderr)
    for line in runner.output_errors:
        print(f"bench: error: {line}", file=sys.stderr)
    for sink in runner_sinks(runner):
        if not getattr(sink, "kept", True):  # removed: never half a file under its name
            again = ""
            if recording is not None and not log_error:
                rec = recording.path
                again = f"; every result is in {rec}: bench log export {rec} --csv {sink.path}"
            print(
                f"bench: error: {sink.path}: not written ({sink.rows} result rows had been "
                f"written when it failed, {sink.rows_lost} not){again}",
                file=sys.stderr,
            )
        elif getattr(sink, "rows_lost", 0):
            print(
                f"bench: error: {sink.path}: {sink.rows_lost} result rows not written "
                f"({sink.rows} written)",
                file=sys.stderr,
            )
    lost = any(
        getattr(s, "rows_lost", 0) or not getattr(s, "kept", True) for s in runner_sinks(runner)
    )
    silent = runner.frames_received == 0
    if silent:  # a channel name typo on a virtual bus looks just like this: say so, exit 1
        kind = "" if stopped else "error: "
        print(f"bench: {kind}{nothing_received(setup.description, start)}", file=sys.stderr)
        silent = not stopped
    return 1 if (runner.error or log_error or runner.output_errors or lost or silent) else 0


def nothing_received(description: str, start: float) -> str:
    """The closing line of a live run that never received a frame."""
    return (
        f"no frame received in {time.monotonic() - start:.1f} s on {description}: is the "
        "channel name right, the bitrate the board's, the board powered and connected?"
    )


def runner_sinks(runner: LiveRunner) -> list[Any]:
    """The run's secondary outputs (what is not the MCAP recording)."""
    return [s for s in runner.sinks if s is not runner.recording]
