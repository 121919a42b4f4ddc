"""The live run: acquisition thread -> bounded queue -> processing thread -> sinks and snapshot.

The receive path never waits on the UI or the disk: the acquisition thread only reads the
source and enqueues (counting what a full queue drops); the processing thread runs the
pipeline and hands each step to the sinks, which queue their own I/O; the UI copies a
:class:`Snapshot` at a few Hz.

On a first start the estimator's kernel is still being compiled (bench.pipeline.warmup):
the runner then holds every batch, runs a preview pipeline on it (the reference method,
the estimator pending) for the screen only, and once the kernel is ready puts everything
held through the full pipeline, in order, to the sinks (the MCAP log gets full rows from
the first frame, tolerance changes and marks where they were made) and replaces the
screen's rows with the full ones. A live run and the replay of its log stay identical.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections import Counter, deque
from typing import TYPE_CHECKING, Any

import numpy as np

from bench.config import Config
from bench.live.view import HISTORY, ResultRing, Snapshot
from bench.pipeline.steps import Pipeline, StepOutput, merge_batches
from bench.pipeline.warmup import KernelWarmUp, PendingEstimator
from bench.records.events import EventKind, concat_events, describe, make_events
from bench.sinks.base import Sink
from devices.base import LiveSource, SourceBatch
from devices.cpu_placement import live_cpus, pin_thread

if TYPE_CHECKING:
    from bench.live.model import LiveModel

MAX_COALESCE = 512
HOLD_MAX_FRAMES = 1_000_000
"""Frames held at most while the estimator's kernel is prepared (about 40 MB; two minutes of
a fully loaded 1 Mbit/s bus, five times the slowest first start seen): a compile that takes
longer, or hangs, costs the log the frames beyond it (counted as ``drop``, a DROPPED event)
instead of the machine its memory."""
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
        warm_up: KernelWarmUp | None = None,
        hold_max_frames: int = HOLD_MAX_FRAMES,
        lag_s: float | None = None,
    ) -> None:
        self.source = source
        self.config = config
        # the explicit model behind the pipeline, on its own thread (`--lag`; None: not run)
        self.model: LiveModel | None = None
        if lag_s is not None:
            from bench.live.model import LiveModel

            self.model = LiveModel(config, lag_s)
        # the estimator's kernel still compiling (first start): a preview pipeline until then
        self._warmup = warm_up if warm_up is not None else KernelWarmUp.if_needed()
        if self._warmup is None:
            self.pipeline = self._attach_model(Pipeline(config))
        else:
            self.pipeline = Pipeline(config, estimator=PendingEstimator())
        self._held: list[tuple[str, Any]] = []  # batches, tolerance changes, marks, events
        self._held_frames = 0
        self._hold_max = hold_max_frames
        self._hold_dropped = 0  # frames the full hold could not keep (processing thread)
        self._hold_drop_event: np.ndarray | None = None  # their DROPPED event, held
        self._previewed: Counter[tuple[float, int, str]] = Counter()  # events shown already
        self._catch_up_ring: ResultRing | None = None
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
        self._queue_dropped = 0  # frames a full queue dropped (acquisition thread)
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
        value = max(0.0, float(permil))
        with self._lock:
            self.pipeline.tolerance_permil = value
            if self._warmup is not None:  # the full pipeline takes it at the same frame
                self._held.append(("tolerance", value))
        self.mark(f"tolerance set to {value:g} permil")

    def mark(self, text: str = "operator mark") -> None:
        t = time.time()
        self.marks += 1
        with self._lock:
            self._events.append((t, int(EventKind.MARK), f"MARK {text}"))
            sinks = list(self._sinks)
            if self._warmup is not None:  # to the sinks after the frames that preceded it
                self._held.append(("mark", (t, text)))
                return
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
                    self._queue_dropped += len(batch.frames)
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
                if self._warmup is not None and self._warmup.ready:
                    self._catch_up()
                try:  # while the kernel is prepared: look up now and then to catch up
                    batch = self._queue.get(timeout=0.1 if self._warmup is not None else None)
                except queue.Empty:
                    continue
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
                merged = merge_batches(parts)
                step = self.pipeline.process(merged)
                extra = None
                if self._queue_dropped != dropped_seen:
                    queue_dropped = self._queue_dropped
                    lost = queue_dropped - dropped_seen
                    dropped_seen = queue_dropped
                    extra = make_events(EventKind.DROPPED, time.time(), 0, -1, lost)
                    step.events = np.concatenate([step.events, extra])
                if self._warmup is not None:
                    self._hold(merged, extra, step)
                else:
                    self._deliver(step)
            if self._warmup is not None:  # the log gets full rows: wait for the kernel
                self._warmup.wait()
                self._catch_up()
            self._deliver(self.pipeline.finish())
            if self.model is not None:  # its last blocks, smoothed given all there is
                self.model.close()
                self._deliver(StepOutput())
        except Exception as exc:
            self.error = f"processing stopped: {exc!r}"
            raise
        finally:
            if self.model is not None:  # stopped by an error: its thread must end too
                self.model.close(timeout=1.0)
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

    # -- while the estimator's kernel is prepared --------------------------------------------
    def _hold(self, batch: SourceBatch, extra: np.ndarray | None, preview: StepOutput) -> None:
        """Keep ``batch`` (and the events the runner added to its step) for the full
        pipeline; the preview's rows and events go to the screen and to the sinks that
        take previews (the engine's row tap, a replay's flow control), not to the log."""
        now = time.time()
        n = len(batch.frames)
        with self._lock:
            if self._held_frames + n <= self._hold_max:
                self._held.append(("batch", batch))
                self._held_frames += n
            else:  # the hold is full: counted, one DROPPED event for the whole streak
                self._hold_dropped += n
                if self._hold_drop_event is None:
                    self._hold_drop_event = make_events(EventKind.DROPPED, now, 0, -1, n)
                    self._held.append(("events", self._hold_drop_event))
                else:  # still in the hold, not yet delivered: its count grows
                    self._hold_drop_event["value"] += n
            if extra is not None:
                self._held.append(("events", extra))
            res = preview.results
            if len(res):
                self._ring.extend(res)
                self._latency.extend(now - res["t"])
            for ev in preview.events[-200:]:
                row = (float(ev["t"]), int(ev["kind"]), describe(ev))
                self._events.append(row)
                self._previewed[row] += 1
            sinks = list(self._sinks)
        for sink in sinks:
            take = getattr(sink, "preview", None)
            if take is not None:
                take(preview)

    def _catch_up(self) -> None:
        """The kernel is ready: everything held through the full pipeline to the sinks, in
        order, then the full pipeline takes over (and the screen's rows are the full ones)."""
        warmup = self._warmup
        assert warmup is not None
        if warmup.error is not None:  # compile here then, or fail with the reason
            try:
                full = Pipeline(self.config)
            except Exception as exc:
                raise RuntimeError(f"the estimator could not be prepared: {warmup.error}") from exc
        else:
            full = Pipeline(self.config)
        self._attach_model(full)
        full.tolerance_permil = self.config.tolerance_permil
        self._catch_up_ring = ResultRing(HISTORY)
        while True:
            with self._lock:
                held, self._held = self._held, []
                self._hold_drop_event = None
                if not held:  # nothing came in meanwhile: the full pipeline takes over
                    full.tolerance_permil = self.pipeline.tolerance_permil
                    self.pipeline = full
                    self._ring, self._catch_up_ring = self._catch_up_ring, None
                    self._warmup = None
                    self._previewed.clear()
                    return
                sinks = list(self._sinks)
            self._replay_held(full, held, sinks)

    def _replay_held(self, full: Pipeline, held: list[tuple[str, Any]], sinks: list[Sink]) -> None:
        segment: list[SourceBatch] = []

        def flush(extra: np.ndarray | None = None) -> None:
            if not segment and extra is None:
                return
            step = full.process(merge_batches(segment)) if segment else StepOutput()
            segment.clear()
            if extra is not None:
                step.events = concat_events([step.events, extra])
            self._deliver(step)

        for kind, item in held:
            if kind == "batch":
                segment.append(item)
                continue
            flush(item if kind == "events" else None)
            if kind == "tolerance":
                full.tolerance_permil = item
            elif kind == "mark":
                for sink in sinks:
                    sink.mark(*item)
        flush()

    def _attach_model(self, pipeline: Pipeline) -> Pipeline:
        """The live model gets what ``pipeline``'s estimator's filter is given."""
        if self.model is not None:
            pipeline.estimator.log = self.model  # type: ignore[attr-defined]  # Estimator's
        return pipeline

    def _deliver(self, step: StepOutput) -> None:
        now = time.time()
        if self.model is not None:  # the rows the model made meanwhile go with this step
            step.model = self.model.take_rows()
            lost = self.model.take_dropped()
            if lost:  # counted on the model panel; told in the log too
                lost_event = make_events(EventKind.MODEL_DROPPED, now, 0, -1, lost)
                step.events = np.concatenate([step.events, lost_event])
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
            ring = self._catch_up_ring
            if ring is not None:  # rows the screen saw as previews: not live, no latency
                if len(res):
                    ring.extend(res)
                rows = [(float(ev["t"]), int(ev["kind"]), describe(ev)) for ev in step.events]
                fresh = [r for r in rows if not self._take_previewed(r)]
                self._events.extend(fresh[-200:])  # the estimator's, which the preview lacked
                return
            if len(res):
                self._ring.extend(res)
                self._latency.extend(now - res["t"])
            for ev in step.events[-200:]:
                self._events.append((float(ev["t"]), int(ev["kind"]), describe(ev)))

    @property
    def frames_dropped(self) -> int:
        """Frames received and never processed for the log: by a full queue, or beyond
        :data:`HOLD_MAX_FRAMES` while the estimator's kernel was prepared."""
        return self._queue_dropped + self._hold_dropped

    def _take_previewed(self, row: tuple[float, int, str]) -> bool:
        """True (and counted off) when the preview showed this event already."""
        if self._previewed[row] <= 0:
            return False
        self._previewed[row] -= 1
        return True

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
            warmup = (
                self._warmup.status(self._held_frames, self._hold_dropped)
                if self._warmup is not None
                else None
            )
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
            warmup=warmup,
            model=self.model.view() if self.model is not None else None,
        )
