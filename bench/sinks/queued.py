"""The caller's side of a sink that works in a thread or process of its own: a bounded queue
that never blocks the processing thread, and the figures for a status line."""

from __future__ import annotations

import atexit
import contextlib
import logging
import queue
import threading
import time
from pathlib import Path
from typing import Any, Self

from bench.config import Config
from bench.pipeline.steps import StepOutput
from bench.sinks.base import RecordingStatus

log = logging.getLogger("bench.mcaplog")  # one logger for everything about MCAP logs

MAX_GROUP = 512
"""Most queued steps the writer thread merges into one encoding pass."""

STOP = object()


class QueuedSink:
    """The caller's side of a live MCAP sink: a bounded queue that never blocks the
    processing thread (a full queue drops the step and counts its frames in ``dropped``),
    and the figures for a status line. Subclasses start the thread that empties the queue
    (``_thread``); :meth:`_stop_thread` ends it after what is queued."""

    def __init__(
        self,
        path: str | Path,
        config: Config,
        queue_size: int,
        flush_interval_s: float,
        group_interval_s: float,
    ) -> None:
        self.path = Path(path)
        self.config = config
        self.flush_interval_s = flush_interval_s
        self.group_interval_s = group_interval_s
        self.error: str | None = None
        self.errors = 0
        self.frames_lost = 0
        self.frames_logged = 0
        self.bytes_written = 0
        self.dropped = 0
        self.dropped_steps = 0
        self._closed = False
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
        self._thread: threading.Thread | None = None

    def write(self, step: StepOutput) -> None:
        if self._closed:  # a write after close() is a caller bug; count it, do not hang
            self.dropped += len(step.frames)
            return
        try:
            self._queue.put_nowait((step, time.time_ns()))
        except queue.Full:
            self.dropped += len(step.frames)
            self.dropped_steps += 1
            if self.dropped_steps == 1:
                log.warning("MCAP log %s: writer queue full, dropping frames (counted)", self.path)

    def mark(self, t: float, text: str) -> None:
        if self._closed:
            return
        try:
            self._queue.put_nowait(("mark", float(t), str(text), time.time_ns()))
        except queue.Full:
            self.dropped_steps += 1
            log.warning("MCAP log %s: queue full, operator mark %r not logged", self.path, text)

    def _stop_thread(self) -> bool:
        """Mark closed, queue the stop after everything queued and wait for the thread;
        False when already closed (close() is idempotent)."""
        if self._closed:
            return False
        self._closed = True
        with contextlib.suppress(Exception):
            atexit.unregister(self.close)
        thread = self._thread
        while thread is not None and thread.is_alive():
            try:
                self._queue.put(STOP, timeout=0.2)
                break
            except queue.Full:
                continue
        if thread is not None and thread.ident is not None:  # never started when not threaded
            thread.join()
        return True

    def _drain(self, items: list[Any]) -> list[Any]:
        """``items`` plus whatever else is queued (up to a group's worth; not past a stop)."""
        while items[-1] is not STOP and len(items) < MAX_GROUP:
            try:
                items.append(self._queue.get_nowait())
            except queue.Empty:
                break
        return items

    def close(self) -> None:
        self._stop_thread()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def queue_depth(self) -> int:
        return self._queue.qsize()

    def status(self) -> RecordingStatus:
        """The recording's figures for a status line or the TUI."""
        return RecordingStatus(
            path=str(self.path),
            frames=self.frames_logged,
            bytes=self.bytes_written,
            dropped=self.dropped,
            lost=self.frames_lost,
            queue=self.queue_depth,
            error=self.error,
            closed=self._closed,
        )
