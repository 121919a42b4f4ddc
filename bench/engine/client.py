"""Live TUI sessions whose run lives in a child process (the engine); this process draws.

Why: a process has one GIL. Textual's rendering holds it in bursts, and the processing
thread of a run in the same process waits behind it (frame-to-result latency p99 ~100 ms
with the TUI attached against ~10 ms without). In the engine process the source, the
in-process board, the LiveRunner and the MCAP writer keep a GIL of their own.

:func:`start_engine` starts the engine (a fresh interpreter, :mod:`devices.child_process`:
the parent has threads, and python-can's virtual bus only connects buses inside one
process, so board and source both live there), sends it a plan (:mod:`bench.engine.plans`)
and returns an :class:`EngineSession`, which offers
the App the same :class:`bench.live.view.SessionLike` as :class:`bench.live.session.Session`.
Snapshots bring only the results new since the last one; the history ring is kept here.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import Config
from bench.engine.plans import EnginePlan
from bench.engine.wire import SIGNALS, EngineReport
from bench.live.view import HISTORY, ReplayControl, ResultRing, Snapshot
from bench.pipeline.stats import Stats
from bench.records.results import RESULT_DTYPE
from bench.sinks.base import RecordingStatus
from devices.child_process import end_child, start_child, wait_child
from devices.cpu_placement import other_cpus, pin_thread, restore_thread

READY_TIMEOUT_S = 300.0
"""Building can simulate a whole scenario (the demo's 10 min at 1 kHz) before it is ready."""
SNAPSHOT_TIMEOUT_S = 10.0
QUICK_TIMEOUT_S = 10.0
RECORDING_TIMEOUT_S = 120.0


class EngineGone(RuntimeError):
    """The engine process is no longer there to answer."""


class _Call:
    __slots__ = ("done", "ok", "on_reply", "value")

    def __init__(self, on_reply: Callable[[Any], Any] | None) -> None:
        self.done = threading.Event()
        self.ok = False
        self.value: Any = None
        self.on_reply = on_reply


class _Channel:
    """Numbered requests to the engine and their replies. A reader thread takes every reply
    (and runs its ``on_reply`` there), so a caller that gave up never leaves one unread --
    a snapshot's new rows reach the ring even then."""

    def __init__(
        self, conn: Any, on_gone: Callable[[], None], on_report: Callable[[Any], None]
    ) -> None:
        self._conn = conn
        self._on_gone = on_gone
        self._on_report = on_report
        self._ids = itertools.count(1)
        self._calls: dict[int, _Call] = {}
        self._lock = threading.Lock()  # the calls table
        self._send_lock = threading.Lock()
        self.gone = False
        self._reader = threading.Thread(target=self._read, name="engine-replies", daemon=True)
        self._reader.start()

    def call(
        self,
        op: str,
        *args: Any,
        timeout: float = QUICK_TIMEOUT_S,
        on_reply: Callable[[Any], Any] | None = None,
    ) -> Any:
        call = _Call(on_reply)
        with self._lock:
            if self.gone:
                raise EngineGone("the engine process has ended")
            n = next(self._ids)
            self._calls[n] = call
        try:
            with self._send_lock:
                self._conn.send((n, op, args))
        except (OSError, ValueError) as exc:
            with self._lock:
                self._calls.pop(n, None)
            raise EngineGone(f"the engine process has ended ({exc})") from None
        if not call.done.wait(timeout):
            raise TimeoutError(f"the engine did not answer {op!r} within {timeout:g} s")
        if call.ok:
            return call.value
        raise call.value

    def _read(self) -> None:
        while True:
            try:
                n, ok, value = self._conn.recv()
            except (EOFError, OSError):
                break
            if n == 0:  # the engine stopped on its own (SIGTERM) and says how it went
                self._on_report(value)
                continue
            with self._lock:
                call = self._calls.pop(n, None)
            if call is None:
                continue
            if ok and call.on_reply is not None:
                try:
                    value = call.on_reply(value)
                except Exception as exc:
                    ok, value = False, exc
            call.ok, call.value = ok, value
            call.done.set()
        with self._lock:
            self.gone = True
            calls, self._calls = list(self._calls.values()), {}
        for call in calls:
            call.value = EngineGone("the engine process has ended")
            call.done.set()
        self._on_gone()

    def wait_gone(self, timeout: float) -> None:
        self._reader.join(timeout)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._conn.close()


@dataclasses.dataclass
class RemoteRunner:
    """What the App and the commands read of the runner, kept current here."""

    config: Config
    description: str = ""
    error: str | None = None
    frames_received: int = 0
    frames_dropped: int = 0
    frames_processed: int = 0


@dataclasses.dataclass(frozen=True)
class DetachedRecording:
    """A recording that was stopped and is being finished by the engine."""

    key: int
    path: Path


class RemoteRecorder:
    """The engine's Recorder as the App drives it. ``active`` is kept here (from each reply)
    so the status bar never waits on the engine; start/detach/finish are requests."""

    def __init__(self, session: EngineSession, hello: dict[str, Any]) -> None:
        self._session = session
        self._active = bool(hello["recording"])
        self._can_start = bool(hello["can_start"])
        self.files: list[Path] = [Path(p) for p in hello["files"]]
        self.last_status: RecordingStatus | None = None

    @property
    def active(self) -> bool:
        return self._active

    @property
    def can_start(self) -> bool:
        return self._can_start and not self._session.stopping

    def update(self, active: bool, can_start: bool) -> None:
        self._active, self._can_start = active, can_start

    def start(self) -> Path:
        """Open a new MCAP file in the engine (its BenchError/OSError come back as they are)."""
        if self._session.stopping:
            raise RuntimeError("the run has stopped")

        def started(path: Path) -> Path:
            self._active = True
            return Path(path)

        path: Path = self._session.call("rec_start", timeout=RECORDING_TIMEOUT_S, on_reply=started)
        if path not in self.files:
            self.files.append(path)
        return path

    def detach(self) -> DetachedRecording | None:
        def detached(got: tuple[int, str] | None) -> DetachedRecording | None:
            self._active = False
            return DetachedRecording(got[0], Path(got[1])) if got is not None else None

        try:
            result: DetachedRecording | None = self._session.call("rec_detach", on_reply=detached)
        except EngineGone:
            return None
        return result

    def finish(self, sink: object | None) -> None:
        """Wait until the engine has finished the file (it does so at the end anyway)."""
        if not isinstance(sink, DetachedRecording):  # None: nothing was being recorded
            return
        with contextlib.suppress(EngineGone):
            self._session.call("rec_finish", sink.key, timeout=RECORDING_TIMEOUT_S)

    def close(self) -> None:
        """The engine closes its files when the run stops (:meth:`EngineSession.stop`)."""


class EngineSession:
    """A live run in the engine process, as the TUI sees it (a :class:`SessionLike`)."""

    mode = "live"
    replay: ReplayControl | None = None  # a live run has no transport
    controllable = True

    def __init__(self, process: Any, conn: Any, hello: dict[str, Any], config: Config) -> None:
        self.pid = int(hello["pid"])
        self.runner = RemoteRunner(config, str(hello["description"]))
        self.recorder = RemoteRecorder(self, hello)
        self.report: EngineReport | None = None
        self._process = process
        self._ring = ResultRing(HISTORY)
        self._ring_lock = threading.Lock()
        self._last: Snapshot | None = None
        self._snap_lock = threading.Lock()
        self._stop_lock = threading.Lock()
        self.stopping = False
        self._stopped = False
        # the screen's thread (and the reader thread it starts) stay off the engine's live
        # CPU until stop(): a screen drawing there delays acquisition (cpu_placement)
        self._placement = pin_thread(other_cpus())
        self._channel = _Channel(conn, self._on_gone, self._finish)

    @property
    def sample_rate_hz(self) -> float:
        return float(self.runner.config.sample_rate_hz)

    @property
    def error(self) -> str | None:
        return self.runner.error

    # -- requests --------------------------------------------------------------------------
    def call(self, op: str, *args: Any, **kwargs: Any) -> Any:
        """One request to the engine (``timeout=``, ``on_reply=`` as in the channel)."""
        return self._channel.call(op, *args, **kwargs)

    def request(self, op: str, *args: Any, timeout: float = 120.0) -> Any:
        """A request the plan answers (:meth:`EnginePlan.request`)."""
        return self.call("plan", op, *args, timeout=timeout)

    def start(self) -> None:
        """The engine started the run as soon as it was built."""

    def snapshot(self, last: int = HISTORY) -> Snapshot:
        with self._snap_lock:
            if not self.stopping:
                try:
                    self.call("snapshot", timeout=SNAPSHOT_TIMEOUT_S, on_reply=self._take)
                except EngineGone:
                    # the send can fail before the reader has seen the end of the pipe:
                    # let it finish (report, error) so this picture says the run is over
                    self._channel.wait_gone(2.0)
            with self._ring_lock:
                base = self._last if self._last is not None else self._empty()
                results = self._ring.last(last)
        # an engine that sent its report (it stopped on SIGTERM) runs no more, whatever
        # the last picture it sent before said
        running = base.running and not self._channel.gone and self.report is None
        return dataclasses.replace(base, results=results, running=running, error=self.runner.error)

    def _take(self, reply: tuple[Snapshot, bool, bool]) -> None:
        """A snapshot's reply, on the reader thread: rows into the ring, state kept."""
        snap, active, can_start = reply
        with self._ring_lock:
            if snap.extra.pop("rows_restart", False):  # full rows replace the previews
                self._ring = ResultRing(HISTORY)
            self._ring.extend(snap.results)
            snap.results = snap.results[:0]
            self._last = snap
        self.recorder.update(active, can_start)
        r = self.runner
        r.frames_received, r.frames_dropped = snap.frames_received, snap.frames_dropped
        r.error = snap.error or r.error

    def _empty(self) -> Snapshot:
        return Snapshot(
            wall=time.time(),
            source=self.runner.description,
            running=False,
            results=np.zeros(0, dtype=RESULT_DTYPE),
            stats=Stats(),
            events=[],
            board=None,
            speed=None,
            frames_received=0,
            frames_dropped=0,
            queue_depth=0,
            queue_max=0,
            tolerance_permil=math.nan,
            latency_ms=(math.nan, math.nan),
            recording=None,
        )

    # -- operator actions ------------------------------------------------------------------
    def mark(self, text: str = "operator mark") -> None:
        with contextlib.suppress(EngineGone):
            self.call("mark", text)

    def tolerance(self) -> float:
        try:
            return float(self.call("tolerance"))
        except EngineGone:
            return float(self._last.tolerance_permil) if self._last is not None else 0.0

    def set_tolerance(self, permil: float) -> None:
        with contextlib.suppress(EngineGone):
            self.call("set_tolerance", permil)

    # -- stopping --------------------------------------------------------------------------
    @property
    def stopped(self) -> bool:
        return self._stopped

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the run in the engine (which finishes every MCAP file), collect its report
        and reap the process. Safe to call twice and from any thread; returns when done."""
        with self._stop_lock:
            if self._stopped:
                return
            self.stopping = True
            try:
                if self.report is None:
                    self._finish(self.call("stop", timeout, timeout=3 * timeout + 30.0))
            except (EngineGone, TimeoutError) as exc:
                self._channel.wait_gone(2.0)  # a report sent unasked may still be on its way
                if self.report is None:
                    self.runner.error = self.runner.error or f"the engine did not stop: {exc}"
            finally:
                self.recorder.update(False, False)
                self._reap()
                restore_thread(self._placement)
                self._stopped = True

    def _finish(self, report: EngineReport) -> None:
        self.report = report
        r = self.runner
        r.error = report.error or r.error
        r.frames_received, r.frames_dropped = report.frames_received, report.frames_dropped
        r.frames_processed = report.frames_processed
        self.recorder.files = [Path(p) for p in report.files]
        self.recorder.last_status = report.last_status
        self.recorder.update(False, False)

    def _reap(self) -> None:
        end_child(self._process, 10.0)
        self._channel.close()

    def _on_gone(self) -> None:
        """The engine's pipe closed: expected after ``stop`` or its report, else a failure."""
        if self.stopping or self.report is not None:
            return
        code = wait_child(self._process, 2.0)
        self.runner.error = self.runner.error or (
            f"the engine process ended unexpectedly (exit code {code})"
        )
        self.recorder.update(False, False)


@contextlib.contextmanager
def _signals_blocked() -> Iterator[None]:
    """Block SIGINT/SIGTERM/SIGHUP while the engine starts: it inherits the mask and
    unblocks them once it ignores them, so a Ctrl-C during its start-up is the parent's."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def start_engine(
    plan: EnginePlan,
    *,
    warn: Callable[[str], None] = lambda m: None,
) -> EngineSession:
    """Start the engine on ``plan`` and wait until its run is going. What goes wrong while
    building (no such bus, log folder unusable) is raised here as the engine raised it."""
    with _signals_blocked():  # the engine inherits the mask and unblocks them itself
        conn, proc = start_child("bench.engine.entry")
    try:
        with contextlib.suppress(OSError):  # an engine that ended already: see below why
            conn.send(plan)
        kind, *rest = _first_message(conn, proc, READY_TIMEOUT_S)
    except BaseException:
        _abandon(proc, conn)
        raise
    for message in rest[-1] if kind == "failed" else rest[0]["warnings"]:
        warn(message)
    if kind == "failed":
        _abandon(proc, conn)
        raise rest[0]
    return EngineSession(proc, conn, rest[0], plan.config)


def _first_message(conn: Any, proc: Any, timeout: float) -> tuple[Any, ...]:
    deadline = time.monotonic() + timeout
    while not conn.poll(0.2):
        if proc.poll() is not None and not conn.poll(0):
            break
        if time.monotonic() > deadline:
            raise TimeoutError(f"the engine process was not ready within {timeout:g} s")
    try:
        return tuple(conn.recv())
    except (EOFError, OSError):
        code = wait_child(proc, 2.0)
        raise EngineGone(
            f"the engine process ended before it was ready (exit code {code})"
        ) from None


def _abandon(proc: Any, conn: Any) -> None:
    """Close the pipe (the engine stops its run and finishes its log on end-of-file) and
    make sure the process is gone."""
    with contextlib.suppress(OSError):
        conn.close()
    end_child(proc, 30.0)
