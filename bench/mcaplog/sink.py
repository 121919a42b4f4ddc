"""The MCAP sink of a live run: queued steps encoded by a writer thread (or by the writer
process, :mod:`bench.mcaplog.writer_process`).

Crash safety: the sink closes the open chunks (and flushes them to the OS) at least every
``flush_interval_s`` of wall time, so a kill -9 loses at most that much; a clean close
writes the summary section (statistics, chunk/metadata/attachment indexes) and the footer.
"""

from __future__ import annotations

import atexit
import dataclasses
import json
import logging
import math
import queue
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import Config
from bench.mcaplog import schemas as S
from bench.mcaplog.encoder import MessageEncoder, config_record, run_record
from bench.mcaplog.file import DEFAULT_CHUNK_SIZE, McapFile, utc_now
from bench.pipeline.stats import Stats
from bench.pipeline.steps import StepOutput, merge_steps
from bench.records.events import EventKind, make_events
from bench.sinks.queued import MAX_GROUP, STOP, QueuedSink
from protocol.batch import decode_batch
from protocol.layout import SPEED_REF_ID, Outcome

log = logging.getLogger("bench.mcaplog")  # one logger for everything about MCAP logs

DEFAULT_FLUSH_INTERVAL_S = 0.5
"""A live chunk is closed and flushed when its first message is this old (wall time)."""
DEFAULT_GROUP_INTERVAL_S = 0.05
"""The live writer encodes the steps that arrive within this long as one group."""


def _outcome(step: StepOutput, base_id: int) -> np.ndarray:
    if len(step.outcome) == len(step.frames):
        return step.outcome
    return decode_batch(step.frames, base_id).outcome


def merge_group(
    items: list[tuple[StepOutput, int]], base_id: int
) -> tuple[StepOutput, int, np.ndarray]:
    """Consecutive queued steps as one (:func:`bench.pipeline.steps.merge_steps`, with each
    step's frame outcomes), the first step's enqueue time, and the index of each step's
    first frame (its source batch start)."""
    steps = [s for s, _ in items]
    sizes = np.array([len(s.frames) for s in steps], dtype=np.int64)
    starts = (np.cumsum(sizes) - sizes)[sizes > 0]
    if len(steps) == 1:
        return steps[0], items[0][1], starts
    merged = merge_steps([dataclasses.replace(s, outcome=_outcome(s, base_id)) for s in steps])
    return merged, items[0][1], starts


class McapSink(QueuedSink):
    """The MCAP sink of a live run (implements bench.sinks.base.Sink).

    ``write`` only enqueues (bounded queue; a full queue drops the step and counts its
    frames in ``dropped``, it never blocks acquisition). A writer thread encodes, closes a
    chunk at least every ``flush_interval_s`` and, on :meth:`close`, drains the queue and
    writes the summary. A write error (disk full, unwritable path) never reaches the
    caller: it is kept in ``error``, logged loudly, and everything after it is counted in
    ``frames_lost``. Counters: ``frames_logged`` (frames in flushed chunks),
    ``bytes_written``, ``dropped``, ``frames_lost``, ``errors``.

    ``threaded=False``: no writer thread; the owner calls the writer-side methods itself
    (the writer process of :mod:`bench.mcaplog.writer_process` does).
    """

    def __init__(
        self,
        path: str | Path,
        config: Config,
        metadata: Mapping[str, str] | None = None,
        attachments: Sequence[tuple[str, bytes]] = (),
        *,
        queue_size: int = 10_000,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "zstd",
        health_interval_s: float = 1.0,
        group_interval_s: float = DEFAULT_GROUP_INTERVAL_S,
        threaded: bool = True,
        result_columns: Sequence[S.Column] | None = None,
    ) -> None:
        """``result_columns``: the results' columns when the rows carry more than
        RESULT_DTYPE (`bench replay --smooth --mcap`: bench.replay.model_columns)."""
        super().__init__(path, config, queue_size, flush_interval_s, group_interval_s)
        self.health_interval_s = health_interval_s
        self._frames_pending = 0
        self._dropped_reported = 0
        self._stats = Stats()
        self._next_health: float | None = None
        self._last_t = math.nan
        self._chunk_opened: float | None = None
        # a merged group stays well inside one chunk (~300 bytes per frame with its results)
        self._group_frames = max(16, chunk_size // 300)
        self._file: McapFile | None = None
        self._enc: MessageEncoder | None = None
        try:
            self._file = self._open_file(chunk_size, compression)
            self._file.add_metadata("run", run_record(metadata))
            self._file.add_metadata("config", config_record(config))
            now = time.time_ns()
            for name, data in attachments:
                self._file.add_attachment(name, data, log_time=now)
            self._enc = MessageEncoder(
                self._file, config.base_id, result_columns=result_columns or S.RESULT_COLUMNS
            )
            self._file.flush_io()
            self.bytes_written = self._file.position
        except OSError as exc:
            self.fail(exc)
        if threaded:  # else the owner drives encode_items/_flush/_finish (writer_process)
            self._thread = threading.Thread(
                target=self._run, name=f"mcap-writer:{self.path.name}", daemon=True
            )
            self._thread.start()
            atexit.register(self.close)

    def close(self) -> None:
        """Drain the queue, write the summary and close the file (idempotent)."""
        self._stop_thread()

    def _open_file(self, chunk_size: int, compression: str) -> McapFile:
        """Where the messages go: a new MCAP file (the live Foxglove stream,
        :mod:`bench.mcaplog.foxglove_ws`, puts a WebSocket server here instead)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        return McapFile(self.path, chunk_size=chunk_size, compression=compression)

    # -- writer thread ---------------------------------------------------------------------
    def fail(self, exc: BaseException) -> None:
        """A write error: kept in ``error`` and logged once; nothing more is written."""
        self.errors += 1
        if self.error is None:
            reason = (
                exc.strerror
                if isinstance(exc, OSError) and exc.strerror
                else str(exc) or type(exc).__name__
            )
            self.error = f"{self.path}: {reason}"
            log.error(
                "MCAP log %s FAILED: %s -- nothing more is logged to it (frames counted as lost)",
                self.path,
                reason,
            )
        if self._file is not None:
            self._settle()  # a lane written before the failure is logged, not lost
            self.frames_lost += self._frames_pending
            self._frames_pending = 0
            self._file.abort()
            self._file = None
            self._enc = None

    def _run(self) -> None:
        while True:
            items, since = self._collect()
            stop = bool(items) and items[-1] is STOP
            if stop:
                items.pop()
            try:
                self.encode_items(items, since)
            except Exception as exc:
                self.fail(exc)
            if stop:
                break
            if (
                self._chunk_opened is not None
                and time.monotonic() - self._chunk_opened >= self.flush_interval_s
            ):
                self.flush_chunks()
        self.finish()

    def _collect(self) -> tuple[list[Any], float]:
        """The next group of queued items, and when its first one was taken.

        After the first item the writer sleeps ``group_interval_s`` (never past the chunk's
        flush deadline) and then takes everything queued: the steps are encoded as one
        group, so the per-step fixed costs (numpy calls on arrays of a few rows, ~400 steps
        a second at 1 kHz) are paid ~20 times a second, in short bursts, instead of holding
        the GIL for every step. Under a backlog it does not sleep.
        """
        deadline = None
        if self._chunk_opened is not None:
            deadline = self._chunk_opened + self.flush_interval_s
        try:
            timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
            items = [self._queue.get(timeout=timeout)]
        except queue.Empty:
            return [], time.monotonic()
        since = time.monotonic()
        if items[0] is not STOP and self._queue.qsize() < MAX_GROUP:
            until = since + min(self.group_interval_s, self.flush_interval_s)
            wait = (until if deadline is None else min(until, deadline)) - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        return self._drain(items), since

    def encode_items(self, items: list[Any], since: float) -> None:
        """Marks in order; each run of consecutive steps merged (see _handle_run).
        ``since``: when the writer took the first of them (the chunk's age counts from it)."""
        run: list[tuple[StepOutput, int]] = []
        for item in items:
            if item[0] == "mark":
                self._handle_run(run, since)
                run = []
                _, t, text, wall = item
                if self._enc is not None:
                    marks = make_events(EventKind.MARK, t)
                    try:
                        self._enc.write_events(marks, wall, name="operator", text=text)
                    except Exception as exc:
                        self.fail(exc)
                    self._opened(since)
            else:
                run.append(item)
        self._handle_run(run, since)

    def _handle_run(self, run: list[tuple[StepOutput, int]], since: float) -> None:
        """Consecutive steps, merged into as few encoding passes as the ~1 Hz health
        snapshots allow (a snapshot must see the counters as of its own step)."""
        start = 0
        frames = 0
        last_t = self._last_t
        for i, (step, wall) in enumerate(run):
            t = step.frames["t"]
            frames += len(t)
            finite = t[np.isfinite(t)] if len(t) else t
            if len(finite):
                last_t = float(finite[-1])
            clock = last_t if math.isfinite(last_t) else wall / 1e9
            if len(t) and self._next_health is None:
                self._next_health = clock + self.health_interval_s
            due = len(t) and self._next_health is not None and clock >= self._next_health
            if due or frames >= self._group_frames or i == len(run) - 1:
                group = run[start : i + 1]
                try:
                    self._handle(*merge_group(group, self.config.base_id), since)
                except Exception as exc:  # the file failed; the rest is counted as lost
                    self.fail(exc)
                start = i + 1
                frames = 0

    def _handle(self, step: StepOutput, wall: int, starts: np.ndarray, since: float) -> None:
        n = len(step.frames)
        self._account(step)
        if self._enc is None:
            self.frames_lost += n
            return
        enc = self._enc
        self._frames_pending += n  # counted before writing: a failure below moves them to lost
        if self.dropped > self._dropped_reported:
            delta = self.dropped - self._dropped_reported
            self._dropped_reported = self.dropped
            t = float(step.frames["t"][0]) if n else self._last_t
            enc.write_events(make_events(EventKind.DROPPED, t, value=delta), wall, name="logger")
        enc.write_frames(step.frames, step.outcome, wall, starts)
        if step.batch is not None:
            enc.write_link_errors(step.batch.link_errors, wall)
            enc.write_notices(step.batch.notices, wall)
        enc.write_samples(step.samples, wall)
        enc.write_results(step.results, wall)
        enc.write_status(step.status, wall)
        enc.write_speed(step.speed, wall)
        enc.write_events(step.events, wall)
        enc.write_model(step.model, wall)
        self._health(step, wall)
        if self._file is not None and self._file.pending_messages:
            self._opened(since)
            if self._file.maybe_flush():
                self._flushed()

    def _opened(self, since: float) -> None:
        if self._chunk_opened is None:
            self._chunk_opened = since

    def _flushed(self) -> None:
        """After chunks were written: frames no longer pending in the file are logged; the
        flush timer restarts only when no chunk is open (lanes are closed independently)."""
        mf = self._file
        if mf is None or not mf.pending_messages:
            self._chunk_opened = None
        self._settle()
        if mf is not None:
            self.bytes_written = mf.position

    def _settle(self) -> None:
        """Move the frames whose chunk was written (and flushed) from pending to logged."""
        if self._file is None or self._enc is None:
            return
        written = self._file.written(self._enc.cid[S.FRAME_TOPIC])
        self._frames_pending -= written - self.frames_logged
        self.frames_logged = written

    def flush_chunks(self) -> None:
        """Close the open chunks and hand them to the OS (what a kill -9 may not lose)."""
        if self._file is None:
            self._chunk_opened = None
            return
        try:
            self._file.flush_chunk()
            self._flushed()
        except Exception as exc:
            self.fail(exc)

    def _account(self, step: StepOutput) -> None:
        st = self._stats
        frames = step.frames
        st.count_frames(frames["id"])
        st.count_events(step.events)
        st.count_results(step.results)
        st.status_frames += len(step.status)
        st.speed_frames += len(step.speed)
        if len(frames) and len(step.outcome) == len(frames):
            ids = frames["id"].astype(np.int64)
            ch = ids - self.config.base_id
            good = (step.outcome == Outcome.OK) & (ch >= 1) & (ch <= 3) & (ids != SPEED_REF_ID)
            for k in range(3):
                sel = good & (ch == k + 1)
                count = int(np.count_nonzero(sel))
                if count:
                    cs = st.channels[k]
                    times = frames["t"][sel]
                    if cs.frames == 0:
                        cs.first_t = float(times[0])
                    cs.last_t = float(times[-1])
                    cs.frames += count
        finite = frames["t"][np.isfinite(frames["t"])] if len(frames) else frames["t"]
        if len(finite):
            self._last_t = float(finite[-1])

    def _health(self, step: StepOutput, wall: int) -> None:
        if self._enc is None or not len(step.frames):
            return
        clock = self._last_t if math.isfinite(self._last_t) else wall / 1e9
        if self._next_health is None:
            self._next_health = clock + self.health_interval_s
        elif clock >= self._next_health:
            self._enc.write_health(self._stats, clock, self.dropped, wall)
            self._next_health = clock + self.health_interval_s

    def finish(self) -> None:
        """Write the summary section and the footer (a clean end of the file)."""
        if self._file is None or self._enc is None:
            return
        try:
            wall = time.time_ns()
            if self._stats.frames:
                clock = self._last_t if math.isfinite(self._last_t) else wall / 1e9
                self._enc.write_health(self._stats, clock, self.dropped, wall)
            self._file.flush_chunk()
            self._flushed()
            self._file.add_metadata("summary", self.summary())
            self._file.finish()
            self.bytes_written = self._file.position
        except Exception as exc:
            self.fail(exc)

    def summary(self) -> dict[str, str]:
        """End-of-run counters, written as the ``summary`` metadata record."""
        enc = self._enc
        return {
            "stopped_utc": utc_now(),
            "frames": str(self._stats.frames),
            "frames_logged": str(self.frames_logged + self._frames_pending),
            "frames_by_id": json.dumps(
                {f"0x{k:03X}": v for k, v in sorted(self._stats.frames_by_id.items())}
            ),
            "dropped_frames": str(self.dropped),
            "frames_lost": str(self.frames_lost),
            "log_errors": str(self.errors),
            "log_time_substituted": str(enc.substituted if enc else 0),
            "stats": json.dumps(self._stats.as_dict()),
        }
