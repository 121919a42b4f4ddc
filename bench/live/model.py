"""The explicit model live (issue 26, `--lag`): its forward pass and fixed-lag smoother on a
thread of their own, behind the pipeline.

The estimator hands each push of what its filter is given (as to a replay's ModelLog) to
:meth:`LiveModel.add`, which copies it onto a bounded queue and returns: the processing
thread never waits on the model, and a full queue drops the push, counted (``dropped``,
shown on the model panel; after a drop the live model is no longer the replay's). The model
thread runs :class:`~bench.fusion.model.stream.ForwardStream` and
:class:`~bench.fusion.model.stream.FixedLag` (compiled without the GIL, so acquisition runs
beside them) and turns each block, once smoothed ``lag`` seconds later, into a
:data:`~bench.records.model.MODEL_DTYPE` row: the MCAP log's ``/bench/model`` messages
(:meth:`take_rows`) and the TUI's model panel and lagged plot line (:meth:`view`).
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from bench.config import Config
from bench.fusion.model import state
from bench.fusion.model.log import gradient_permil
from bench.fusion.model.stream import Blocks, FixedLag, ForwardStream, Lagged
from bench.live.view import ModelView
from bench.records.model import MODEL_DTYPE, NO_MODEL_ROWS
from devices.cpu_placement import other_cpus, pin_thread

QUEUE_SAMPLES = 300_000
"""Samples queued for the model at most (5 min at 1 kHz, about 12 MB): room for the first
start's compile of its kernels; beyond it a push is dropped and counted."""
PLOT_BLOCKS = 3000
"""Lagged gradient points a snapshot carries for the plot (a minute of 20 ms blocks)."""
CLOSE_TIMEOUT_S = 60.0
"""How long closing waits for the model to work off its queue."""

PERIOD_S = 0.05
"""The model thread wakes at most this often: woken by every live push (about a thousand a
second at 1 kHz) its Python part took the GIL from acquisition each time (latency p50
1.2-1.4 ms without the model, 2.0-2.3 ms with it woken per push, load 2-4)."""
MAX_MERGE = 4096
"""Queued pushes the model thread takes as one at most."""

_STOP = None


class LiveModel:
    """See the module docstring; ``lag_s`` >= 0 (0: the filter's estimates alone)."""

    def __init__(self, config: Config, lag_s: float, max_samples: int | None = None) -> None:
        self.config = config
        self.lag_s = max(0.0, float(lag_s))
        self._fwd = ForwardStream(config)
        self.block = self._fwd.block
        block_s = self.block / config.sample_rate_hz
        self._lag = FixedLag(round(self.lag_s / block_s), config.g)
        self._queue: queue.Queue[tuple[Any, ...] | None] = queue.Queue()
        self._max = QUEUE_SAMPLES if max_samples is None else max_samples
        self._queued = 0  # samples on the queue
        self.dropped_pushes = 0
        self.dropped_samples = 0
        self._dropped_told = 0  # of dropped_samples, those take_dropped has told
        self._lock = threading.Lock()
        self._rows: list[np.ndarray] = []  # rows not yet taken for the log
        self._plot: deque[tuple[float, float, float]] = deque(maxlen=PLOT_BLOCKS)
        self._latest: np.void | None = None  # the filter's newest block, as a row
        self._pending = NO_MODEL_ROWS  # filtered rows waiting for their lagged values
        self._recv = np.zeros(0)  # receive times of the samples of the block not complete
        self.blocks = 0
        self.ready = False  # the kernels are loaded
        self.error: str | None = None
        self._thread = threading.Thread(target=self._run, name="model", daemon=True)
        self._thread.start()

    # -- the processing thread's side ------------------------------------------------------------
    def add(
        self,
        b: np.ndarray,
        acc: np.ndarray,
        mask: np.ndarray,
        frames: tuple[np.ndarray, ...] | None,
        t: np.ndarray | None = None,
    ) -> None:
        """One push as :meth:`ModelLog.add <bench.fusion.model.log.ModelLog.add>` takes it,
        with ``t`` the samples' receive times; copied and queued, or dropped when full."""
        n = len(b)
        with self._lock:
            if self._queued + n > self._max:
                self.dropped_pushes += 1
                self.dropped_samples += n
                return
            self._queued += n
        keep = None if frames is None else tuple(np.array(c) for c in frames)
        recv = np.full(n, math.nan) if t is None else np.array(t, dtype=np.float64)
        self._queue.put((np.array(b), np.array(acc), np.array(mask), keep, recv))

    def take_rows(self) -> np.ndarray:
        """The rows made since the last call (for the log), in block order."""
        with self._lock:
            rows, self._rows = self._rows, []
        if not rows:
            return NO_MODEL_ROWS
        return rows[0] if len(rows) == 1 else np.concatenate(rows)

    def take_dropped(self) -> int:
        """Samples dropped since the last call (for a MODEL_DROPPED event in the log)."""
        with self._lock:
            new = self.dropped_samples - self._dropped_told
            self._dropped_told = self.dropped_samples
        return new

    def view(self) -> ModelView:
        with self._lock:
            plot = np.array(self._plot, dtype=np.float64).reshape(len(self._plot), 3)
            latest = None if self._latest is None else self._latest.copy()
            return ModelView(
                lag_s=self.lag_s,
                latest=latest,
                lagged=plot,
                blocks=self.blocks,
                queued_samples=self._queued,
                dropped_pushes=self.dropped_pushes,
                dropped_samples=self.dropped_samples,
                ready=self.ready,
                error=self.error,
            )

    def close(self, timeout: float = CLOSE_TIMEOUT_S) -> None:
        """Work off the queue, smooth the last blocks given all there is, stop the thread."""
        self._queue.put(_STOP)
        self._thread.join(timeout)
        if self._thread.is_alive() and self.error is None:
            self.error = f"the model had not worked off its queue after {timeout:g} s"

    # -- the model thread ------------------------------------------------------------------------
    def _run(self) -> None:
        pin_thread(other_cpus())  # off the live path's CPU, with the writer and the screen
        try:
            self._warm_up()
            self.ready = True
            end = False
            while not end:
                # whatever else waits goes into the same push: the stream's blocks do not
                # depend on the cut, and a live push of a few samples costs mostly overhead
                items = [self._queue.get()]
                if items[0] is not _STOP:
                    time.sleep(PERIOD_S)  # let pushes gather: one wake-up, not one per push
                while items[-1] is not _STOP and len(items) < MAX_MERGE:
                    try:
                        items.append(self._queue.get_nowait())
                    except queue.Empty:
                        break
                end = items[-1] is _STOP
                pushes = [i for i in items if i is not _STOP]
                if pushes:
                    b, acc, mask, frames, recv = _merge(pushes)
                    with self._lock:
                        self._queued -= len(b)
                    self._recv = np.concatenate([self._recv, recv])
                    self._emit(self._fwd.push(b, acc, mask, frames), self._recv)
            self._emit(self._fwd.finish(), self._recv, final=True)
        except Exception as exc:  # the model must not stop the run: said on its panel
            self.error = f"the model stopped: {exc!r}"
            with contextlib.suppress(Exception):
                while self._queue.get_nowait() is not _STOP:
                    pass

    def _warm_up(self) -> None:
        """Compile or load the kernels on a throw-away stream of two blocks."""
        fwd, lag = ForwardStream(self.config), FixedLag(1, self.config.g)
        n = 2 * self.block
        b = np.arange(n) / self.config.sample_rate_hz
        frames = (np.zeros(1, np.int64), b[:1], np.zeros(1), np.ones(1, bool), np.zeros(1, bool))
        lag.push(fwd.push(b, np.zeros((n, 3)), np.full(n, 7), frames))

    def _emit(self, blocks: Blocks, recv: np.ndarray, final: bool = False) -> None:
        """Rows of the new blocks: filtered now, lagged once FixedLag gives them."""
        m = len(blocks)
        last = np.minimum(np.arange(1, m + 1) * self.block, len(recv)) - 1
        fresh = self._filtered_rows(blocks, recv[last])
        self._recv = recv[len(recv) if final else m * self.block :]
        lagged = self._lag.push(blocks)
        if final:
            tail = self._lag.finish()
            lagged = Lagged(
                *(np.concatenate([getattr(lagged, f), getattr(tail, f)]) for f in Lagged.__slots__)
            )
        self._pending = np.concatenate([self._pending, fresh])
        k = len(lagged)
        rows, self._pending = self._pending[:k].copy(), self._pending[k:]
        rows["gradient_lagged"] = lagged.gradient
        rows["gradient_lagged_sigma"] = lagged.gradient_sigma
        with self._lock:
            self.blocks += m
            if m:
                self._latest = fresh[-1]
            if k:
                self._rows.append(rows)
                self._plot.extend(
                    zip(
                        rows["board_t"].tolist(),
                        rows["gradient_lagged"].tolist(),
                        rows["gradient_lagged_sigma"].tolist(),
                        strict=True,
                    )
                )

    def _filtered_rows(self, blocks: Blocks, recv_t: np.ndarray) -> np.ndarray:
        """The blocks' rows as the filter has them (the lagged gradient NaN until known)."""
        x = blocks.x_filt
        sig = np.sqrt(np.maximum(np.diagonal(blocks.p_filt, axis1=1, axis2=2), 0.0))
        rows = np.zeros(len(blocks), dtype=MODEL_DTYPE)
        rows["block"] = self.blocks + np.arange(len(blocks))
        rows["t"] = recv_t
        rows["board_t"] = blocks.t
        rows["gradient"], rows["gradient_sigma"] = gradient_permil(
            x[:, state.S], blocks.p_filt[:, state.S, state.S], self.config.g
        )
        rows["gradient_lagged"] = rows["gradient_lagged_sigma"] = math.nan
        rows["lag_s"] = self.lag_s
        rows["wheel_error"], rows["wheel_error_sigma"] = x[:, state.E], sig[:, state.E]
        rows["compliance"] = np.degrees(x[:, state.C])
        rows["compliance_sigma"] = np.degrees(sig[:, state.C])
        rows["bias"] = x[:, list(state.BIASES)]
        rows["bias_sigma"] = sig[:, list(state.BIASES)]
        return rows


def _merge(pushes: list[tuple[Any, ...]]) -> tuple[Any, ...]:
    """Consecutive pushes as one: samples concatenated, each push's frames anchored into
    the whole."""
    if len(pushes) == 1:
        return pushes[0]
    cols: list[list[np.ndarray]] = [[] for _ in range(5)]
    at = 0
    for b, _, _, frames, _ in pushes:
        if frames is not None and len(frames[0]):
            cols[0].append(np.asarray(frames[0], dtype=np.int64) + at)
            for c in range(1, 5):
                cols[c].append(np.asarray(frames[c]))
        at += len(b)
    frames_all = tuple(np.concatenate(c) for c in cols) if cols[0] else None
    return (
        np.concatenate([p[0] for p in pushes]),
        np.concatenate([np.asarray(p[1]).reshape(len(p[0]), 3) for p in pushes]),
        np.concatenate([p[2] for p in pushes]),
        frames_all,
        np.concatenate([p[4] for p in pushes]),
    )
