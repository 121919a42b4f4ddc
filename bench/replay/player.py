"""A log file played back as a live source: 1x / 10x / max, pause, step, run to the next failure.

The TUI drives a replay exactly like a live run (LiveRunner, snapshots, sinks), so a replayed
log looks and behaves like the bench did on the day. Pacing lives here, in the source, and
not in the runner: the runner's acquisition thread just calls :meth:`ReplaySource.read`,
which hands out the frames that are due at the chosen speed.

Flow control: the runner drops batches when its queue is full, which a replay must never
cause. So the source only runs ahead of the pipeline by a bounded number of frames; the
pipeline's progress comes back through :class:`ReplayTap`, a sink added to the runner.
The same tap ends a "run to the next vote failure" seek: it pauses the source as soon as a
step carrying a VOTE_FAIL event goes by, and records which sample it was.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from bench.records.events import EventKind, describe
from bench.sinks.base import Sink
from devices.base import FileSource, LiveSource, SourceBatch

if TYPE_CHECKING:  # a type only: the screen process imports this module, not the pipeline
    from bench.pipeline.steps import StepOutput

SPEEDS: tuple[float | None, ...] = (1.0, 10.0, None)
"""The speeds the TUI cycles through; None = as fast as the pipeline takes frames."""

MAX_IDLE_GAP_S = 2.0
"""A pause in the log longer than this is skipped when pacing (a log may hold hours of idle)."""

SEEK_AHEAD_S = 0.5
"""A seek runs at most this much log time ahead of what fusion has taken: it stops that close
past the event it looks for (the plot still shows it), in steps large enough for the
pipeline's fast path. A seek to a time hands out everything before it in full batches."""


def speed_label(speed: float | None) -> str:
    return "max" if speed is None else f"{speed:g}x"


@dataclass
class Failure:
    """Where a seek stopped: the first event of the kinds sought after the seek began (or
    the first sample at or after the log time sought)."""

    t: float
    n: int
    text: str


FAULT_KINDS = frozenset(
    {
        EventKind.CRC_ERROR,
        EventKind.WRONG_DLC,
        EventKind.DUPLICATE,
        EventKind.LATE,
        EventKind.GAP,
        EventKind.SAMPLES_LOST,
        EventKind.COUNTER_JUMP,
        EventKind.STATUS_FLAG,
        EventKind.LINK_ERROR,
        EventKind.PARSE_ERROR,
        EventKind.DISCONNECT,
    }
)
"""What "the next fault" means: anything wrong on the bus, a channel or the link."""

SEEK_TARGETS: tuple[tuple[str, frozenset[int]], ...] = (
    ("vote failure", frozenset({EventKind.VOTE_FAIL})),
    ("INVALID", frozenset({EventKind.INVALID})),
    ("exclusion", frozenset({EventKind.EXCLUDED})),
    ("fault", FAULT_KINDS),
    ("mark", frozenset({EventKind.MARK})),
)
"""What ``j`` can run to (``t`` cycles through them). Marks come from the log's own event
record (an MCAP file), not from fusion: the seek runs to the next recorded mark's time."""


@dataclass
class ReplayStatus:
    """What the UI shows about the replay (copied under the source's lock)."""

    description: str
    speed: float | None
    paused: bool
    seeking: bool
    finished: bool
    emitted: int
    consumed: int
    log_t: float
    log_t0: float
    position: int  # bytes read from the file (0 when unknown)
    size: int  # file size in bytes (0 when unknown)
    failure: Failure | None = None
    notes: list[str] = field(default_factory=list)
    frames_total: float = math.nan  # frames in the log (estimated from bytes when not told)
    seek_until: float = math.nan  # log time a seek runs to (NaN: none, or to an event)

    @property
    def fraction(self) -> float:
        """How far fusion has got through the log: by frames, which move with every step
        (a file's position moves by whole chunks: a chunk of an MCAP log can be 30 s)."""
        if self.finished and self.consumed >= self.emitted:
            return 1.0
        if math.isfinite(self.frames_total) and self.frames_total > 0:
            return min(1.0, self.consumed / self.frames_total)
        return self.position / self.size if self.size else math.nan

    @property
    def seek_fraction(self) -> float:
        """How far a seek to a log time has got (NaN when the seek is not to a time)."""
        span = self.seek_until - self.log_t0
        if not (self.seeking and math.isfinite(span) and span > 0 and math.isfinite(self.log_t)):
            return math.nan
        return min(1.0, max(0.0, (self.log_t - self.log_t0) / span))


class ReplaySource(LiveSource):
    """Plays a :class:`FileSource` in real time, faster, or as fast as the pipeline goes."""

    def __init__(
        self,
        log: FileSource,
        *,
        speed: float | None = 1.0,
        paused: bool = False,
        step_s: float = 1.0 / 200,
        batch_frames: int = 2048,
        max_ahead: int = 16384,
        max_ahead_batches: int = 256,
        seek_chunk: int = 64,
        clock: Callable[[], float] = time.monotonic,
        description: str | None = None,
    ) -> None:
        self.log = log
        self.description = description or f"replay {getattr(log, 'description', 'log')}"
        self._batches: Iterator[SourceBatch] = iter(log.batches(batch_frames))
        self._frames_told = _frames_in(log)  # the log says how many frames it holds
        self._frames_read = 0  # frames taken from the log so far
        self._clock = clock
        self._cond = threading.Condition()
        self._speed = speed
        self._paused = paused
        self.step_s = step_s
        self.max_ahead = max(1, max_ahead)
        self.max_ahead_batches = max(1, max_ahead_batches)
        self.seek_chunk = max(1, seek_chunk)
        # the batch being handed out, and how far into it we are
        self._pending: SourceBatch | None = None
        self._pos = 0
        self._extras_sent = False
        self._exhausted = False
        self._closed = False
        self.emitted = 0  # frames handed to the runner
        self.consumed = 0  # frames the pipeline has processed (from ReplayTap)
        self.batches_emitted = 0
        self.batches_consumed = 0
        self._log_t = math.nan  # log time of the last frame handed out
        self._log_t0 = math.nan  # log time of the first frame
        self._anchor: tuple[float, float] | None = None  # (clock, log time) pacing reference
        self._step_target = math.nan  # while paused: hand out frames up to this log time
        self._seeking = False
        self._seek_kinds: frozenset[int] = frozenset({EventKind.VOTE_FAIL})
        self._seek_until = math.nan  # log time a seek runs to (NaN: run to an event)
        self.failure: Failure | None = None
        self._notes: list[str] = []

    # -- controls (UI thread) -------------------------------------------------------------
    @property
    def speed(self) -> float | None:
        return self._speed

    @property
    def paused(self) -> bool:
        return self._paused

    def set_speed(self, speed: float | None) -> None:
        with self._cond:
            self._speed = speed
            self._anchor = None
            self._cond.notify_all()

    def cycle_speed(self) -> float | None:
        i = SPEEDS.index(self._speed) if self._speed in SPEEDS else -1
        self.set_speed(SPEEDS[(i + 1) % len(SPEEDS)])
        return self._speed

    def play(self) -> None:
        with self._cond:
            self._paused = False
            self._seeking = False
            self._anchor = None
            self._step_target = math.nan
            self._cond.notify_all()

    def pause(self) -> None:
        with self._cond:
            self._paused = True
            self._seeking = False
            self._step_target = math.nan
            self._cond.notify_all()

    def toggle(self) -> bool:
        """Play if paused, pause if playing; returns the new paused state."""
        if self._paused:
            self.play()
        else:
            self.pause()
        return self._paused

    def step(self, periods: int = 1) -> None:
        """While paused: hand out the next ``periods`` sample periods of log time."""
        with self._cond:
            self._paused = True
            self._seeking = False
            base = self._step_target if math.isfinite(self._step_target) else self._log_t
            if not math.isfinite(base):
                base = self._next_frame_t() - 1e-9
            self._step_target = base + periods * self.step_s
            self._cond.notify_all()

    def seek_failure(self) -> None:
        """Run as fast as possible until the pipeline reports a vote failure, then pause."""
        self.seek_event(frozenset({EventKind.VOTE_FAIL}))

    def seek_event(self, kinds: frozenset[int]) -> None:
        """Run as fast as possible until the pipeline reports an event of ``kinds``, then
        pause there."""
        with self._cond:
            self.failure = None
            self._seek_kinds = frozenset(int(k) for k in kinds)
            self._seek_until = math.nan
            self._seeking = True
            self._paused = False
            self._cond.notify_all()

    def seek_time(self, log_t: float) -> None:
        """Run as fast as possible until the pipeline has fused the sample at log time
        ``log_t`` (seconds, the log's clock), then pause there."""
        with self._cond:
            self.failure = None
            self._seek_kinds = frozenset()
            self._seek_until = float(log_t)
            self._seeking = True
            self._paused = False
            self._cond.notify_all()

    @property
    def seeking(self) -> bool:
        return self._seeking

    @property
    def seek_kinds(self) -> frozenset[int]:
        return self._seek_kinds

    @property
    def seek_until(self) -> float:
        return self._seek_until

    @property
    def finished(self) -> bool:
        """Every frame of the log has been handed out."""
        return self._exhausted and self._pending is None

    def status(self) -> ReplayStatus:
        with self._cond:
            return ReplayStatus(
                description=self.description,
                speed=self._speed,
                paused=self._paused,
                seeking=self._seeking,
                finished=self.finished,
                emitted=self.emitted,
                consumed=self.consumed,
                log_t=self._log_t,
                log_t0=self._log_t0,
                position=_safe(self.log.position),
                size=_safe(self.log.size_bytes),
                failure=self.failure,
                notes=list(self._notes),
                frames_total=self._frames_total(),
                seek_until=self._seek_until if self._seeking else math.nan,
            )

    def _frames_total(self) -> float:
        """The log's frames: as it says, else from the frames read per byte so far."""
        if self._frames_told:
            return float(self._frames_told)
        if self._exhausted:
            return float(self._frames_read)
        position, size = _safe(self.log.position), _safe(self.log.size_bytes)
        if position <= 0 or size <= 0 or not self._frames_read:
            return math.nan
        return self._frames_read * size / position

    # -- feedback (processing thread, via ReplayTap) --------------------------------------
    def consumed_to(self, frames: int, batches: int) -> None:
        with self._cond:
            self.batches_consumed = max(self.batches_consumed, batches)
            self.consumed = max(self.consumed, frames)
            self._cond.notify_all()

    def failure_found(self, failure: Failure) -> None:
        with self._cond:
            if self._seeking:
                self.failure = failure
                self._seeking = False
                self._paused = True
                self._step_target = math.nan
                self._cond.notify_all()

    # -- LiveSource -----------------------------------------------------------------------
    def read(self, timeout: float) -> SourceBatch:
        deadline = self._clock() + max(0.0, timeout)
        while True:
            self._fill()
            with self._cond:
                if self._closed:
                    return SourceBatch()
                batch, wait = self._take()
                if batch:
                    return batch
                if self._pending is None and not self._exhausted:
                    continue  # the batch was all extras or empty: fetch the next one
                remaining = deadline - self._clock()
                if remaining <= 0:
                    return SourceBatch()
                self._cond.wait(min(remaining, wait))
                if self._clock() >= deadline:
                    return SourceBatch()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        with contextlib.suppress(Exception):
            self.log.close()

    # -- internals ------------------------------------------------------------------------
    def _fill(self) -> None:
        """Fetch the next batch from the file (outside the lock: only this thread reads it)."""
        if self._pending is not None or self._exhausted:
            return
        try:
            batch = next(self._batches)
        except StopIteration:
            batch = None
        except Exception as exc:  # a reader must not raise, but a replay must survive one that does
            with self._cond:
                self._notes.append(f"reading the log stopped: {exc!r}")
            batch = None
        with self._cond:
            if batch is None:
                self._exhausted = True
            else:
                self._pending, self._pos, self._extras_sent = batch, 0, False
                self._frames_read += len(batch.frames)
                if not math.isfinite(self._log_t0) and len(batch.frames):
                    finite = batch.frames["t"][np.isfinite(batch.frames["t"])]
                    if len(finite):
                        self._log_t0 = float(finite[0])

    def _next_frame_t(self) -> float:
        p = self._pending
        if p is None or self._pos >= len(p.frames):
            return self._log_t if math.isfinite(self._log_t) else 0.0
        return float(p.frames["t"][self._pos])

    def _take(self) -> tuple[SourceBatch, float]:
        """Frames due now (under the lock), and how long to wait when none are."""
        p = self._pending
        if p is None:
            return SourceBatch(), 0.05
        frames = p.frames[self._pos :]
        ahead = self.emitted - self.consumed
        if self.batches_emitted - self.batches_consumed >= self.max_ahead_batches:
            return SourceBatch(), 0.05  # the runner's queue counts batches: do not fill it
        if len(frames) == 0:
            k = 0
        elif self._seeking:
            k = self._seek_take(frames, ahead)
        elif self._paused:
            k = self._due(frames, self._step_target) if math.isfinite(self._step_target) else 0
            k = min(k, max(0, self.max_ahead - ahead))
        elif self._speed is None:
            k = min(len(frames), max(0, self.max_ahead - ahead))
        else:
            k = min(self._due(frames, self._paced_target(frames)), max(0, self.max_ahead - ahead))
        wait = 0.05
        if k == 0 and len(frames) and not self._paused and self._speed and not self._seeking:
            target = self._paced_target(frames)
            t_next = float(frames["t"][0])
            if math.isfinite(t_next) and math.isfinite(target):
                wait = min(0.05, max(0.0005, (t_next - target) / self._speed))
        out = frames[:k]
        batch = SourceBatch(out.copy()) if k else SourceBatch()
        if not self._extras_sent and (k or len(frames) == 0):
            # link errors and notices go out with the first frames of their batch
            batch.link_errors, batch.notices = list(p.link_errors), list(p.notices)
            self._extras_sent = True
        self._pos += k
        self.emitted += k
        if batch:
            self.batches_emitted += 1
        if k:
            t = out["t"][np.isfinite(out["t"])]
            if len(t):
                self._log_t = float(t[-1])
        if self._pos >= len(p.frames):
            self._pending = None
        return batch, wait

    def _seek_take(self, frames: np.ndarray, ahead: int) -> int:
        """Frames a seek hands out now: up to :data:`SEEK_AHEAD_S` of log time past what
        fusion has taken (at least ``seek_chunk`` frames), and when it seeks a time, every
        frame that far before it, in full batches."""
        span = self._log_t - self._log_t0
        per_s = self.emitted / span if span > 0.1 else 0.0  # the log's frame rate so far
        limit = max(self.seek_chunk, int(per_s * SEEK_AHEAD_S))
        k = min(len(frames), max(0, limit - ahead))
        if math.isfinite(self._seek_until):
            before = self._due(frames, self._seek_until - SEEK_AHEAD_S)
            k = max(k, min(before, max(0, self.max_ahead - ahead)))
        return k

    def _paced_target(self, frames: np.ndarray) -> float:
        """The log time that is due now at the current speed."""
        now = self._clock()
        t_next = float(frames["t"][0])
        if not math.isfinite(t_next):
            return math.inf  # no receive times in this log: pace by flow control only
        if self._anchor is None:
            start = self._log_t if math.isfinite(self._log_t) else t_next
            self._anchor = (now, start)
        wall0, log0 = self._anchor
        target = log0 + (now - wall0) * (self._speed or 1.0)
        if t_next - target > MAX_IDLE_GAP_S:
            self._anchor = (now, t_next)  # skip a long idle stretch in the log
            target = t_next
        return target

    @staticmethod
    def _due(frames: np.ndarray, target: float) -> int:
        """Leading frames with t <= target (frames without a time go with their neighbours)."""
        t = frames["t"]
        if not math.isfinite(target):
            return len(frames) if target > 0 else 0
        due = ~(t > target)  # NaN counts as due
        if due.all():
            return len(frames)
        return int(np.argmin(due))


def _frames_in(log: FileSource) -> int:
    """Frames the log says it holds (an MCAP log's summary), 0 when it does not say."""
    count = getattr(log, "frame_count", None)
    try:
        return int(count()) if callable(count) else 0
    except Exception:
        return 0


def _safe(fn: Callable[[], int]) -> int:
    try:
        return int(fn())
    except Exception:
        return 0


class ReplayTap(Sink):
    """Sink that reports pipeline progress back to the :class:`ReplaySource` (flow control,
    seek to the next vote failure). Add it to the runner before starting it."""

    def __init__(self, source: ReplaySource) -> None:
        self.source = source
        self.dropped = 0  # frames the runner dropped: handed out, never processed
        self.batches = 0
        self._fused_to = 0  # frames counted so far (the runner's catch-up repeats previews)

    def write(self, step: StepOutput) -> None:
        source = self.source
        end = step.seq0 + len(step.frames)
        fresh = end > self._fused_to or not len(step.frames)  # not a catch-up of previews
        if len(step.events):
            kinds = step.events["kind"]
            if fresh:
                self.dropped += int(step.events["value"][kinds == EventKind.DROPPED].sum())
            if source.seeking and source.seek_kinds:
                hits = step.events[np.isin(kinds, list(source.seek_kinds))]
                if len(hits):
                    ev = hits[0]
                    source.failure_found(Failure(float(ev["t"]), int(ev["n"]), describe(ev)))
        until = source.seek_until
        if source.seeking and math.isfinite(until) and len(step.results):
            t = step.results["t"]
            due = np.flatnonzero(t >= until)
            if len(due):
                k = int(due[0])
                n = int(step.results["n"][k])
                source.failure_found(Failure(float(t[k]), n, f"sample {n}"))
        if step.batch is not None and fresh:
            self._fused_to = end
            self.batches += 1
            self.source.consumed_to(step.seq0 + len(step.frames) + self.dropped, self.batches)

    def preview(self, step: StepOutput) -> None:
        """While the estimator's kernel is prepared the runner previews its steps: they
        move the replay on as much as the full ones (bench.live.runner)."""
        self.write(step)
