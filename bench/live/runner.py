"""The live run: acquisition thread -> bounded queue -> processing thread -> sinks and snapshot.

The receive path never waits on the UI or the disk: the acquisition thread only reads the
source and enqueues (counting what a full queue drops); the processing thread runs the
pipeline and hands each step to the sinks, which queue their own I/O; the UI copies a
:class:`Snapshot` at a few Hz.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from bench.config import Config
from bench.live.view import HISTORY, ResultRing, Snapshot
from bench.pipeline.steps import Pipeline, StepOutput, merge_batches
from bench.records.events import EventKind, describe, make_events
from bench.sinks.base import Sink
from devices.base import LiveSource, SourceBatch
from devices.cpu_placement import live_cpus, pin_thread

MAX_COALESCE = 512
"""Queued source batches merged into one pipeline step at most."""


class LatencyRing:
    """The last ``size`` frame-to-result latencies (s), finite ones only, in a numpy ring:
    a snapshot copies 40 kB instead of turning a deque of floats into an array."""

    def __init__(self, size: int) -> None:
        self._buf = np.zeros(size, dtype=np.float64)
        self._n = 0  # values written so far

    def extend(self, lat: np.ndarray) -> None:
        lat = lat[np.isfinite(lat)]
        size = len(self._buf)
        if len(lat) >= size:  # the newest value lands where the ring would have put it
            self._n += len(lat)
            self._buf[:] = np.roll(lat[-size:], self._n % size)
            return
        i = self._n % size
        k = min(len(lat), size - i)
        self._buf[i : i + k] = lat[:k]
        self._buf[: len(lat) - k] = lat[k:]
        self._n += len(lat)

    def values(self) -> np.ndarray:
        """A copy of the values kept (order does not matter for percentiles)."""
        return self._buf[: min(self._n, len(self._buf))].copy()


CLOSE_TIMEOUT_S = 120.0
"""How long :meth:`LiveRunner.stop` waits for the processing thread to close the sinks."""


class LiveRunner:
    def __init__(
        self,
        source: LiveSource,
        config: Config,
        sinks: list[Sink] | None = None,
        *,
        description: str = "",
        queue_batches: int = 4096,
        read_timeout: float = 0.05,
    ) -> None:
        self.source = source
        self.config = config
        self.pipeline = Pipeline(config)
        self.description = description or getattr(source, "description", "live source")
        self._sinks: list[Sink] = list(sinks or [])
        self._queue: queue.Queue[SourceBatch | None] = queue.Queue(maxsize=queue_batches)
        self._read_timeout = read_timeout
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._ring = ResultRing(HISTORY)
        self._events: deque[tuple[float, int, str]] = deque(maxlen=500)
        self._latency = LatencyRing(5000)
        self.frames_received = 0
        self.frames_dropped = 0
        self.marks = 0
        self.error: str | None = None
        self.output_errors: list[str] = []  # one line per failed secondary output
        self._failed: set[int] = set()  # id() of the sinks that failed
        self._carry_events: list[np.ndarray] = []  # output failures, for the next step
        self.finished = threading.Event()
        self.recording: Any = None  # the MCAP sink, when recording
        self.cpus = live_cpus()  # both threads on one CPU: they share a GIL (cpu_placement)
        self._acq = threading.Thread(target=self._acquire, name="acquisition", daemon=True)
        self._proc = threading.Thread(target=self._process, name="processing", daemon=True)

    # -- control ---------------------------------------------------------------------------
    def start(self) -> LiveRunner:
        self._acq.start()
        self._proc.start()
        return self

    def stop(self, timeout: float = 10.0, close_timeout: float = CLOSE_TIMEOUT_S) -> None:
        """Stop acquisition, drain the queue through the pipeline, flush and close sinks.

        Acquisition ends within ``timeout``; the processing thread, which works off what is
        still queued and then closes the sinks (the MCAP summary, the CSV), gets up to
        ``close_timeout``: a backlog on a loaded machine takes long, and a run that returned
        before its sinks were closed would end its process with an unfinished log. Past
        that, :attr:`error` says so."""
        self._stop.set()
        self._acq.join(timeout)
        self._proc.join(max(timeout, close_timeout))
        if self._proc.is_alive() and self.error is None:
            self.error = (
                f"closing the run's outputs took longer than {max(timeout, close_timeout):g} s: "
                "its log may be unfinished"
            )
        with contextlib.suppress(Exception):
            self.source.close()

    def wait(self, timeout: float | None = None) -> bool:
        return self.finished.wait(timeout)

    @property
    def sinks(self) -> list[Sink]:
        with self._lock:
            return list(self._sinks)

    def add_sink(self, sink: Sink) -> None:
        with self._lock:
            self._sinks.append(sink)

    def set_tolerance(self, permil: float) -> None:
        self.pipeline.tolerance_permil = max(0.0, float(permil))
        self.mark(f"tolerance set to {self.pipeline.tolerance_permil:g} permil")

    def mark(self, text: str = "operator mark") -> None:
        t = time.time()
        self.marks += 1
        with self._lock:
            self._events.append((t, int(EventKind.MARK), f"MARK {text}"))
            sinks = list(self._sinks)
        for sink in sinks:
            sink.mark(t, text)

    # -- threads ---------------------------------------------------------------------------
    def _acquire(self) -> None:
        pin_thread(self.cpus)
        try:
            while not self._stop.is_set():
                batch = self.source.read(self._read_timeout)
                if not batch:
                    continue
                self.frames_received += len(batch.frames)
                try:
                    self._queue.put_nowait(batch)
                except queue.Full:
                    self.frames_dropped += len(batch.frames)
        except Exception as exc:  # a source must not raise, but the run must survive one that does
            self.error = f"acquisition stopped: {exc!r}"
        finally:
            self._queue.put(None)

    def _process(self) -> None:
        pin_thread(self.cpus)
        dropped_seen = 0
        try:
            end = False
            while not end:
                batch = self._queue.get()
                if batch is None:
                    break
                # whatever else is waiting goes into the same step: the pipeline's output does
                # not depend on batching, and a backlog then shrinks instead of growing
                parts = [batch]
                while len(parts) < MAX_COALESCE:
                    try:
                        more = self._queue.get_nowait()
                    except queue.Empty:
                        break
                    if more is None:
                        end = True
                        break
                    parts.append(more)
                step = self.pipeline.process(merge_batches(parts))
                if self.frames_dropped != dropped_seen:
                    lost = self.frames_dropped - dropped_seen
                    dropped_seen = self.frames_dropped
                    step.events = np.concatenate(
                        [step.events, make_events(EventKind.DROPPED, time.time(), 0, -1, lost)]
                    )
                self._deliver(step)
            self._deliver(self.pipeline.finish())
        except Exception as exc:
            self.error = f"processing stopped: {exc!r}"
            raise
        finally:
            with self._lock:
                sinks = list(self._sinks)
            # secondary outputs first: a failure they find while finishing (the last rows,
            # a full disk) still reaches the MCAP log as an event
            sinks.sort(key=lambda s: s is self.recording)
            for sink in sinks:
                if sink is self.recording and self._carry_events:
                    with contextlib.suppress(Exception):
                        sink.write(StepOutput(events=np.concatenate(self._carry_events)))
                    self._carry_events = []
                try:
                    sink.close()
                except Exception as exc:  # a failing sink must not hide the others
                    self.error = f"closing {type(sink).__name__} failed: {exc!r}"
                error = getattr(sink, "error", None)
                if error and id(sink) not in self._failed and sink is not self.recording:
                    self._output_failed(sink, str(error), int(getattr(sink, "errno", 0) or 0))
            self.finished.set()

    def _deliver(self, step: StepOutput) -> None:
        now = time.time()
        with self._lock:
            sinks = list(self._sinks)
        if self._carry_events:  # told in the step after the failure: the MCAP logs it too
            step.events = np.concatenate([step.events, *self._carry_events])
            self._carry_events = []
        for sink in sinks:
            if id(sink) in self._failed and getattr(sink, "error", None) is None:
                continue  # it raised: not asked again
            try:
                sink.write(step)
            except Exception as exc:  # a secondary output must not stop the run
                self._output_failed(sink, f"{type(sink).__name__} failed: {exc!r}", 0)
                continue
            error = getattr(sink, "error", None)
            if error and id(sink) not in self._failed and sink is not self.recording:
                self._output_failed(sink, str(error), int(getattr(sink, "errno", 0) or 0))
        res = step.results
        with self._lock:
            if len(res):
                self._ring.extend(res)
                self._latency.extend(now - res["t"])
            for ev in step.events[-200:]:
                self._events.append((float(ev["t"]), int(ev["kind"]), describe(ev)))

    def _output_failed(self, sink: Sink, text: str, errno: int) -> None:
        """A secondary output failed: a loud event, a line for the status and the exit code;
        the pipeline, the MCAP log and the other outputs go on."""
        self._failed.add(id(sink))
        t = time.time()
        self._carry_events.append(make_events(EventKind.OUTPUT_ERROR, t, 0, -1, errno))
        with self._lock:
            self.output_errors.append(text)
            self._events.append((t, int(EventKind.OUTPUT_ERROR), f"OUTPUT_ERROR {text}"))

    # -- snapshot --------------------------------------------------------------------------
    def snapshot(self, last: int = HISTORY) -> Snapshot:
        with self._lock:  # held for two memcpys: the processing thread waits on it
            results = self._ring.last(last)
            stats = self.pipeline.stats.copy()
            events = list(self._events)
            lat = self._latency.values()
        rec = None
        if self.recording is not None:
            rec = getattr(self.recording, "status", lambda: None)()
        p50, p99 = np.percentile(lat * 1000.0, (50, 99)).tolist() if len(lat) else (np.nan, np.nan)
        return Snapshot(
            wall=time.time(),
            source=self.description,
            running=not self.finished.is_set(),
            results=results,
            stats=stats,
            events=events,
            board=self.pipeline.last_status,
            speed=self.pipeline.last_speed,
            frames_received=self.frames_received,
            frames_dropped=self.frames_dropped,
            queue_depth=self._queue.qsize(),
            queue_max=self._queue.maxsize,
            tolerance_permil=self.pipeline.tolerance_permil,
            latency_ms=(p50, p99),
            recording=rec,
            error=self.error,
            marks=self.marks,
            output_errors=list(self.output_errors),
        )
