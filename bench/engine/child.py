"""The engine process: builds a plan's session, runs it, and answers the screen's requests.

Runs acquisition, the pipeline, the MCAP writer (and the in-process board) away from the
TUI's process, so that rendering never holds the GIL the processing thread needs. The main
thread only answers requests, and those are cheap: a snapshot is the small state plus the
results new since the last one (:class:`RowTap`), not the whole history. Slow requests
(closing a file, a plan's own requests) run on their own threads.

The process ends with its parent: the request pipe reaching end-of-file (the parent died)
stops the run like ``q`` would, so the MCAP file is finished even then. SIGINT and SIGHUP
(terminal events that reach the whole process group) are the parent's to handle; SIGTERM
stops the run here, sends the report unasked (request number 0) and exits.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import signal
import sys
import tempfile
import threading
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench.engine.plans import EnginePlan
from bench.engine.wire import SIGNALS, EngineReport
from bench.live.view import HISTORY
from bench.pipeline.steps import StepOutput
from bench.records.arrays import concat_records
from bench.records.results import RESULT_DTYPE
from bench.sinks.base import Sink

SLOW_OPS = frozenset({"rec_finish", "plan"})
OUTPUT_TAIL = 8000


class RowTap(Sink):
    """A sink keeping the results delivered since the last :meth:`take` (at most ``limit``
    rows: the screen's history holds no more), so a snapshot sends only what is new.

    While the estimator's kernel is prepared it also takes the runner's previews (rows
    without the estimator); the first full rows after them replace them: :meth:`take` then
    says the screen must start its history afresh."""

    def __init__(self, limit: int = HISTORY) -> None:
        self._limit = limit
        self._lock = threading.Lock()
        self._parts: list[np.ndarray] = []
        self._rows = 0
        self._previewing = False
        self._restart = False

    def preview(self, step: StepOutput) -> None:
        with self._lock:
            self._previewing = True
            self._add(step.results)

    def write(self, step: StepOutput) -> None:
        with self._lock:
            if self._previewing:  # the full rows from the first frame on: previews go
                self._previewing, self._restart = False, True
                self._parts, self._rows = [], 0
            self._add(step.results)

    def _add(self, res: np.ndarray) -> None:
        if not len(res):
            return
        self._parts.append(res)
        self._rows += len(res)
        while self._rows - len(self._parts[0]) >= self._limit:
            self._rows -= len(self._parts.pop(0))

    def take(self) -> tuple[np.ndarray, bool]:
        """The rows new since the last take, and whether they replace all rows before."""
        with self._lock:
            parts, self._parts, self._rows = self._parts, [], 0
            restart, self._restart = self._restart, False
        if not parts:
            return np.zeros(0, dtype=RESULT_DTYPE), restart
        rows = concat_records(parts)  # np.concatenate: ~50 us of GIL per part
        return rows[-self._limit :], restart


def portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError saying what it was; unexpected
    errors carry the engine's traceback as a note."""
    from bench.errors import BenchError

    if not isinstance(exc, BenchError | OSError):
        tb = "".join(traceback.format_exception(exc)).rstrip()
        with contextlib.suppress(Exception):
            exc.add_note(f"in the engine process:\n{tb}")
    try:
        return pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")


class ProblemLog(logging.Handler):
    """Exceptions in threads and ERROR records, collected (the engine's parent cannot see
    this process's; the soak checks its own run with the same)."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.seen: list[str] = []
        self._previous_hook = threading.excepthook

    def emit(self, record: logging.LogRecord) -> None:
        self.seen.append(f"{record.name}: {record.getMessage()}")

    def install(self) -> None:
        logging.getLogger().addHandler(self)
        previous = self._previous_hook = threading.excepthook

        def hook(args: threading.ExceptHookArgs) -> None:
            name = args.thread.name if args.thread else "?"
            self.seen.append(f"thread {name}: {args.exc_value!r}")
            previous(args)

        threading.excepthook = hook

    def uninstall(self) -> None:
        threading.excepthook = self._previous_hook
        logging.getLogger().removeHandler(self)


def child_main(conn: Any, plan: EnginePlan) -> None:
    """Run the engine in this process (started by :mod:`bench.engine.entry`)."""
    for sig in SIGNALS:
        signal.signal(sig, signal.SIG_IGN)  # until the run exists; then SIGTERM stops it
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)
    problems = ProblemLog()
    problems.install()
    warnings: list[str] = []
    session: Any = None
    try:
        session = plan.build(warnings.append)
        tap = RowTap()
        session.runner.add_sink(tap)
        session.start()
        server = _Server(conn, session, tap, plan, problems)
        plan.started(session)
    except BaseException as exc:
        if session is not None:
            session.stop()
        with contextlib.suppress(OSError):
            conn.send(("failed", portable(exc), warnings))
        return
    signal.signal(signal.SIGTERM, lambda *_: server.stop_soon())
    try:
        conn.send(("ready", server.hello(warnings)))
    except OSError:  # the parent is gone already
        server.stop()
        return
    server.capture_output()
    server.serve()


class _Server:
    """Answers the parent's requests for one running session (see the module docstring)."""

    def __init__(
        self, conn: Any, session: Any, tap: RowTap, plan: EnginePlan, problems: ProblemLog
    ) -> None:
        self.conn = conn
        self.session = session
        self.tap = tap
        self.plan = plan
        self.problems = problems
        self._send_lock = threading.Lock()
        self._stop_lock = threading.Lock()
        self._detached: dict[int, Any] = {}
        self._output: Any = None
        self._ops: dict[str, Callable[..., Any]] = {
            "snapshot": self.snapshot,
            "mark": session.mark,
            "tolerance": session.tolerance,
            "set_tolerance": session.set_tolerance,
            "rec_start": self.rec_start,
            "rec_detach": self.rec_detach,
            "rec_finish": self.rec_finish,
            "plan": self.plan_request,
        }

    def hello(self, warnings: list[str]) -> dict[str, Any]:
        rec = self.session.recorder
        return {
            "pid": os.getpid(),
            "description": self.session.runner.description,
            "files": list(rec.files),
            "recording": rec.active,
            "can_start": rec.can_start,
            "warnings": warnings,
        }

    def capture_output(self) -> None:
        """From now on the parent's screen is up: what this process prints would scribble
        over it, so keep it and hand it back with the report."""
        with contextlib.suppress(OSError, ValueError):
            sys.stdout.flush()
            sys.stderr.flush()
            self._output = tempfile.TemporaryFile()  # noqa: SIM115 - read back at the end
            for fd in (1, 2):
                os.dup2(self._output.fileno(), fd)

    # -- the request loop --------------------------------------------------------------------
    def serve(self) -> None:
        while True:
            try:
                n, op, args = self.conn.recv()
            except (EOFError, OSError):  # the parent died: finish the log and leave
                self.stop()
                return
            if op == "stop":
                self._answer(n, self.final_report, args)
                return
            if op in SLOW_OPS:
                threading.Thread(
                    target=self._answer, args=(n, self._ops[op], args), daemon=True
                ).start()
            else:
                self._answer(n, self._ops.get(op, self._unknown(op)), args)

    @staticmethod
    def _unknown(op: str) -> Callable[..., Any]:
        def fail(*_: Any) -> Any:
            raise ValueError(f"unknown engine request {op!r}")

        return fail

    def _answer(self, n: int, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        try:
            reply: tuple[int, bool, Any] = (n, True, fn(*args))
        except Exception as exc:
            reply = (n, False, portable(exc))
        with self._send_lock, contextlib.suppress(OSError):
            self.conn.send(reply)

    # -- requests ----------------------------------------------------------------------------
    def snapshot(self) -> tuple[Any, bool, bool]:
        """The state without results, plus the results new since the last snapshot."""
        snap = self.session.snapshot(last=0)
        snap.results, restart = self.tap.take()
        if restart:
            snap.extra["rows_restart"] = True
        rec = self.session.recorder
        return snap, rec.active, rec.can_start

    def rec_start(self) -> Path:
        return self.session.recorder.start()

    def rec_detach(self) -> tuple[int, str] | None:
        sink = self.session.recorder.detach()
        if sink is None:
            return None
        self._detached[id(sink)] = sink
        return id(sink), str(getattr(sink, "path", ""))

    def rec_finish(self, key: int) -> None:
        sink = self._detached.pop(key, None)
        if sink is not None:
            self.session.recorder.finish(sink)

    def plan_request(self, op: str, *args: Any) -> Any:
        return self.plan.request(op, self.session, *args)

    # -- stopping ----------------------------------------------------------------------------
    def stop(self, timeout: float = 10.0) -> None:
        """Stop the run once; a second caller waits until the first has finished the log."""
        with self._stop_lock:
            self.session.stop(timeout)

    def stop_soon(self) -> None:
        """SIGTERM: stop the run, send the report unasked, and leave (the parent may be
        exiting itself and waiting for this process: it must not wait for a request)."""

        def stop_and_leave() -> None:
            try:
                report = self.final_report()
                with self._send_lock, contextlib.suppress(OSError):
                    self.conn.send((0, True, report))
            finally:
                os._exit(0)  # files are closed; the main thread is blocked reading the pipe

        threading.Thread(target=stop_and_leave, name="engine-stop", daemon=True).start()

    def final_report(self, timeout: float = 10.0) -> EngineReport:
        self.stop(timeout)
        s, runner, rec = self.session, self.session.runner, self.session.recorder
        board = None
        if s.setup is not None and s.setup.emulator is not None:
            em = s.setup.emulator
            board = {"frames_sent": int(em.frames_sent), "errors": int(em.errors)}
        return EngineReport(
            error=runner.error,
            frames_received=runner.frames_received,
            frames_dropped=runner.frames_dropped,
            frames_processed=runner.pipeline.seq,
            files=list(rec.files),
            last_status=rec.last_status,
            board=board,
            stats=runner.pipeline.stats.as_dict(),
            problems=list(self.problems.seen),
            output=self._read_output(),
            plan=self.plan.report(s),
        )

    def _read_output(self) -> str:
        if self._output is None:
            return ""
        with contextlib.suppress(OSError, ValueError):
            sys.stdout.flush()
            sys.stderr.flush()
            self._output.seek(0, os.SEEK_END)
            size = self._output.tell()
            self._output.seek(max(0, size - OUTPUT_TAIL))
            return self._output.read().decode("utf-8", "replace")
        return ""
