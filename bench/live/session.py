"""What the TUI drives: a running LiveRunner, its source, the MCAP recorder, replay controls.

The App talks to it only through :class:`bench.live.view.SessionLike`; it never touches
the runner's threads. Building a Session (which source, which log file) is the commands'
job, so the App can be tested with a fixed snapshot and no runner at all. A live
``bench tui`` or ``bench demo`` builds its Session in the engine process and the App drives
it through :class:`bench.engine.client.EngineSession`, the other SessionLike.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.config import Config
from bench.live.runner import LiveRunner
from bench.live.setup import DEFAULT_LOG_DIR, LiveSetup, default_log_path, start_recording
from bench.live.view import HISTORY, Snapshot
from bench.pipeline.steps import StepOutput
from bench.replay.player import ReplaySource, ReplayTap
from bench.sinks.base import RecordingStatus, Sink


class Recorder:
    """The runner's one recording sink: forwards to the current MCAP sink, if any.

    Starting and stopping a recording swaps the sink behind a lock, so the processing thread
    never writes to a sink that is being closed, and the runner's own sink list never changes
    while it runs. When the runner stops it closes the Recorder, which closes the MCAP sink:
    that is how quitting finalises the file.
    """

    def __init__(self, open_sink: Callable[[], Any] | None = None, sink: Any = None) -> None:
        self._open_sink = open_sink
        self._lock = threading.Lock()  # the processing thread writes through it: held briefly
        self._start_lock = threading.Lock()
        self._sink: Any = sink
        self._closed = False
        self.last_status: RecordingStatus | None = None  # of the last file, once stopped
        self.files: list[Path] = []
        self._started = time.time()  # wall time the current file was opened
        self._pending: dict[int, Any] = {}  # detached, not yet being closed
        self._closing: dict[int, threading.Event] = {}  # being closed; set when done
        if sink is not None:
            self.files.append(Path(sink.path))

    @property
    def active(self) -> bool:
        return self._sink is not None

    @property
    def can_start(self) -> bool:
        return self._open_sink is not None and not self._closed

    @property
    def path(self) -> Path | None:
        s = self._sink
        return Path(s.path) if s is not None else None

    def start(self) -> Path:
        """Open a new MCAP file and record into it (BenchError if it cannot be created).

        The file is opened *outside* the lock the processing thread writes every step
        through: opening a recording starts its writer process and waits for the first
        reply (0.3-1 s, longer on a loaded machine), and a processing thread waiting that
        long delivered a second of results hundreds of ms late (latency p99 264-396 ms in
        `bench demo` for as long as they stayed in the TUI's window). Only the swap is under
        the lock. A run that stops while the file opens gets it closed here, so no file is
        left unfinished."""
        if self._open_sink is None:
            raise RuntimeError("this session cannot record")
        with self._start_lock:  # one start at a time (the UI and a plan could both ask)
            with self._lock:
                if self._closed:
                    raise RuntimeError("the run has stopped")
                if self._sink is not None:
                    return Path(self._sink.path)
            sink = self._open_sink()
            with self._lock:
                late = self._closed
                if not late:
                    self._sink = sink
                    self._started = time.time()
                    self.files.append(Path(sink.path))
            if late:
                sink.close()
                raise RuntimeError("the run has stopped")
            return Path(sink.path)

    def detach(self) -> Any:
        """Stop recording; returns the sink, which the caller closes (off the UI thread)."""
        with self._lock:
            sink, self._sink = self._sink, None
            if sink is not None:
                self._pending[id(sink)] = sink
        return sink

    def finish(self, sink: Any) -> None:
        """Close a detached sink (once, whoever gets there first: the UI's worker or the
        runner's shutdown) and keep its final status for the UI."""
        if sink is None:
            return
        with self._lock:
            if self._pending.pop(id(sink), None) is None:
                return
            done = self._closing[id(sink)] = threading.Event()
        duration = time.time() - self._started
        try:
            sink.close()
            with contextlib.suppress(Exception):
                status = with_duration(recording_status(sink), duration)
                if status.error:  # its writer's count is not what the file holds
                    from bench.mcaplog.recorded import count_frames

                    status = dataclasses.replace(status, file_frames=count_frames(status.path))
                self.last_status = status
        finally:
            done.set()
            with self._lock:
                self._closing.pop(id(sink), None)

    def status(self) -> RecordingStatus | None:
        s = self._sink
        if s is None:
            return None
        try:
            return with_duration(recording_status(s), time.time() - self._started)
        except Exception as exc:  # the UI must survive a sink that cannot report
            return RecordingStatus(path=str(getattr(s, "path", "?")), error=repr(exc))

    # -- Sink -----------------------------------------------------------------------------
    def write(self, step: StepOutput) -> None:
        with self._lock:
            if self._sink is not None:
                self._sink.write(step)

    def mark(self, t: float, text: str) -> None:
        with self._lock:
            if self._sink is not None:
                self._sink.mark(t, text)

    def close(self) -> None:
        """The runner is done: close the current file and any still being closed, and wait
        for them, so that quitting never leaves an unfinished MCAP file behind."""
        with self._lock:
            current, self._sink = self._sink, None
            self._closed = True
            if current is not None:
                self._pending[id(current)] = current
            todo = list(self._pending.values())
            closing = list(self._closing.values())
        for sink in todo:
            self.finish(sink)
        for done in closing:
            done.wait(60.0)


def recording_status(sink: Any) -> RecordingStatus:
    """A recording's figures: its ``status()``, else its McapSink-style counters."""
    fn = getattr(sink, "status", None)
    if callable(fn):
        status = fn()
        if not isinstance(status, RecordingStatus):
            raise TypeError(f"{type(sink).__name__}.status() returned {type(status).__name__}")
        return status
    return RecordingStatus(
        path=str(getattr(sink, "path", "?")),
        frames=getattr(sink, "frames_logged", None),
        bytes=getattr(sink, "bytes_written", None),
        dropped=getattr(sink, "dropped", 0),
        error=getattr(sink, "error", None),
    )


def with_duration(status: RecordingStatus, duration_s: float) -> RecordingStatus:
    """The status with its duration, unless the sink reported one itself."""
    if status.duration_s is not None:
        return status
    return dataclasses.replace(status, duration_s=duration_s)


@dataclass
class Session:
    """A live or replay run in this process, as the TUI sees it (a :class:`SessionLike`)."""

    runner: LiveRunner | None
    recorder: Recorder = field(default_factory=Recorder)
    setup: LiveSetup | None = None
    replay: ReplaySource | None = None
    fixed: Snapshot | None = None  # tests: always show this snapshot
    on_stop: list[Callable[[], None]] = field(default_factory=list)
    _started: bool = False
    _stopped: bool = False
    _stop_lock: threading.Lock = field(default_factory=threading.Lock)

    @classmethod
    def create(
        cls,
        setup: LiveSetup,
        runner_factory: Callable[[list[Sink]], LiveRunner],
        open_sink: Callable[[], Any] | None,
        first_sink: Any = None,
    ) -> Session:
        """Wire recorder (and replay tap) into a new runner; the runner is not started."""
        recorder = Recorder(open_sink, first_sink)
        replay = setup.source if isinstance(setup.source, ReplaySource) else None
        sinks: list[Sink] = [recorder]
        if replay is not None:
            sinks.insert(0, ReplayTap(replay))
        runner = runner_factory(sinks)
        runner.recording = recorder
        return cls(runner=runner, recorder=recorder, setup=setup, replay=replay)

    @property
    def mode(self) -> str:
        return "replay" if self.replay is not None else "live"

    @property
    def controllable(self) -> bool:
        return self.runner is not None

    @property
    def sample_rate_hz(self) -> float:
        return float(self.runner.config.sample_rate_hz) if self.runner is not None else 1000.0

    @property
    def error(self) -> str | None:
        return self.runner.error if self.runner is not None else None

    def start(self) -> None:
        if self.runner is not None and not self._started:
            self._started = True
            self.runner.start()
            if self.setup is not None:
                self.setup.start_board()

    def snapshot(self, last: int = HISTORY) -> Snapshot:
        if self.fixed is not None or self.runner is None:
            assert self.fixed is not None, "a session needs a runner or a fixed snapshot"
            return self.fixed
        snap = self.runner.snapshot(last)
        if self.setup is not None and self.setup.emulator is not None:
            snap.extra["frames_sent"] = getattr(self.setup.emulator, "frames_sent", None)
            snap.extra["emulator_done"] = bool(getattr(self.setup.emulator, "done", False))
        if self.replay is not None:
            snap.extra["replay"] = self.replay.status()
        if self.setup is not None and "foxglove" in self.setup.metadata:
            snap.extra["foxglove"] = self.setup.metadata["foxglove"]  # the live stream's address
        if snap.recording is None and self.recorder.last_status is not None:
            snap.extra["last_recording"] = self.recorder.last_status
        return snap

    # -- operator actions -----------------------------------------------------------------
    def mark(self, text: str = "operator mark") -> None:
        if self.runner is not None:
            self.runner.mark(text)

    def tolerance(self) -> float:
        if self.runner is not None:
            return float(self.runner.pipeline.tolerance_permil)
        return float(self.fixed.tolerance_permil) if self.fixed is not None else 0.0

    def set_tolerance(self, permil: float) -> None:
        if self.runner is not None:
            self.runner.set_tolerance(permil)

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the board, the runner (drains and closes every sink: the MCAP summary gets
        written) and the source. Safe to call twice and from any thread."""
        with self._stop_lock:
            if self._stopped:
                return
            self._stopped = True
        setup = self.setup
        if setup is not None and setup.emulator is not None:
            with contextlib.suppress(Exception):
                setup.emulator.stop()
        if self.runner is not None and self._started:
            self.runner.stop(timeout)
            self.runner.wait(timeout)
        else:  # never started: nothing will close the sinks for us
            with contextlib.suppress(Exception):
                self.recorder.close()
        if setup is not None:
            with contextlib.suppress(Exception):
                setup.close()
        for fn in self.on_stop:
            with contextlib.suppress(Exception):
                fn()

    @property
    def stopped(self) -> bool:
        return self._stopped


def wait_until(pred: Callable[[], bool], timeout: float, interval: float = 0.02) -> bool:
    """Poll ``pred`` until true or ``timeout`` s pass (for commands and tests, never the UI)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(interval)
    return pred()


# -- building sessions (for the commands) --------------------------------------------------
def live_session(
    setup: LiveSetup,
    config: Config,
    first_sink: Any = None,
    log_dir: Path = DEFAULT_LOG_DIR,
    *,
    record: bool = True,
    lag_s: float | None = None,
) -> Session:
    """A session on a live source; ``r`` opens new files in ``log_dir``; ``lag_s``: the
    live model with that fixed lag (None: no model)."""

    def open_sink() -> Any:
        return start_recording(default_log_path(setup.slug, log_dir), setup, config)

    return Session.create(
        setup,
        lambda sinks: LiveRunner(
            setup.source, config, sinks, description=setup.description, lag_s=lag_s
        ),
        open_sink if record else None,
        first_sink,
    )


def replay_setup(
    path: str | Path, config: Config, *, speed: float | None = 1.0, paused: bool = False
) -> LiveSetup:
    """A LiveSetup whose source plays the log ``path`` (see :class:`ReplaySource`)."""
    from devices.formats import open_log

    p = Path(path)
    source = ReplaySource(
        open_log(p),
        speed=speed,
        paused=paused,
        step_s=1.0 / config.sample_rate_hz,
        description=f"replay {p.name}",
    )
    return LiveSetup(source, f"replay {p.name}", f"replay-{p.stem}"[:40])
