"""The live MCAP sink with its encoder in a process of its own.

Why: encoding a live run (a JSON object per result, chunk building) is pure Python. In the
bench process it runs in bursts of a few milliseconds, and while it holds the GIL the
acquisition and processing threads wait. Here the bench process only queues each step
and a sender thread ships each group of queued steps, merged into one set of arrays
(~0.5 ms per 50 ms group), to a writer process at idle CPU priority that runs the very same
:class:`~bench.mcaplog.sink.McapSink` code without its thread. (Measured on 2 cores: the
encoder's CPU still shows in the live latency p99 wherever it runs -- see
docs/BENCHMARKS.md -- but as competition for a core, not as GIL stalls of the bench
process.)

The front (:class:`McapProcessSink`) has McapSink's interface and counters; the writer's
figures (frames logged, bytes, error) come back after every group. Crash safety gets
better, not worse: the writer process ignores Ctrl-C, SIGTERM and SIGHUP in a session of its
own (the bench process decides when the run ends) and finishes the file when its socket
closes, so a bench process killed with -9 still leaves a finished MCAP file.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import math
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import Config
from bench.mcaplog.sink import DEFAULT_FLUSH_INTERVAL_S, DEFAULT_GROUP_INTERVAL_S, McapSink
from bench.pipeline.steps import STEP_ARRAYS, StepOutput, merge_steps
from bench.sinks.queued import MAX_GROUP, STOP, QueuedSink
from devices.base import SourceBatch
from devices.child_process import end_child, parent_connection, start_child
from devices.cpu_placement import other_cpus, pin_thread, yield_cpu

log = logging.getLogger("bench.mcaplog")

START_TIMEOUT_S = 60.0
"""How long the writer process may take to start and open the file."""
CLOSE_TIMEOUT_S = 120.0
"""How long closing may take (the writer drains what was sent and writes the summary)."""
WRITER_GROUP_S = 0.25
"""The writer process encodes what arrived in groups this far apart: its fixed cost per
group (a dozen topics, each a few numpy calls) is then paid 4 times a second."""
_CHILD_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)


# -- transport: consecutive steps as one set of arrays ---------------------------------------
def pack_steps(items: Sequence[tuple[StepOutput, int]]) -> dict[str, Any]:
    """Steps (with their enqueue wall times) as one picklable dict: every array field
    concatenated once, plus each step's lengths to cut them apart again. Pickling the steps
    one by one costs ~50 us each; this ~10 us per step."""
    steps = [s for s, _ in items]
    batches = [s.batch for s in steps]
    merged = merge_steps(steps)
    return {
        "arrays": {name: getattr(merged, name) for name in STEP_ARRAYS},
        "sizes": np.array([[len(getattr(s, n)) for n in STEP_ARRAYS] for s in steps], np.int64),
        "seq0": [s.seq0 for s in steps],
        "wall": [w for _, w in items],
        "has_batch": [b is not None for b in batches],
        "link_errors": [list(b.link_errors) if b is not None else [] for b in batches],
        "notices": [list(b.notices) if b is not None else [] for b in batches],
    }


def unpack_steps(packed: dict[str, Any]) -> list[tuple[StepOutput, int]]:
    """The inverse of :func:`pack_steps` (each step's arrays are views of the merged ones)."""
    arrays = packed["arrays"]
    ends = np.cumsum(packed["sizes"], axis=0)
    starts = ends - packed["sizes"]
    out: list[tuple[StepOutput, int]] = []
    for i, wall in enumerate(packed["wall"]):
        part = {
            name: arrays[name][int(starts[i, k]) : int(ends[i, k])]
            for k, name in enumerate(STEP_ARRAYS)
        }
        batch = None
        if packed["has_batch"][i]:
            batch = SourceBatch(part["frames"], packed["link_errors"][i], packed["notices"][i])
        out.append((StepOutput(**part, seq0=packed["seq0"][i], batch=batch), wall))
    return out


def _pack_items(items: list[Any]) -> list[Any]:
    """Queued items (steps and operator marks, in order) as runs of packed steps and marks."""
    out: list[Any] = []
    run: list[tuple[StepOutput, int]] = []
    for item in items:
        if item[0] == "mark":
            if run:
                out.append(("steps", pack_steps(run)))
                run = []
            out.append(item)
        else:
            run.append(item)
    if run:
        out.append(("steps", pack_steps(run)))
    return out


def _unpack_items(packed: list[Any]) -> list[Any]:
    items: list[Any] = []
    for part in packed:
        if part[0] == "steps":
            items += unpack_steps(part[1])
        else:
            items.append(part)
    return items


# -- the writer process ----------------------------------------------------------------------
def _writer_status(sink: McapSink) -> dict[str, Any]:
    return {
        "frames_logged": sink.frames_logged,
        "bytes_written": sink.bytes_written,
        "frames_lost": sink.frames_lost,
        "errors": sink.errors,
        "error": sink.error,
        "port": getattr(sink, "port", None),
        "viewers": sink.viewer_counts() if hasattr(sink, "viewer_counts") else {},
    }


def _make_sink(
    path: str, config: Config, metadata: Any, attachments: Any, options: dict[str, Any]
) -> McapSink:
    """The sink the writer process runs: the MCAP file, or (``sink="foxglove"``) the live
    Foxglove stream, which is the same code writing to a WebSocket server."""
    kind = options.pop("sink", "mcap")
    if kind == "foxglove":
        from bench.mcaplog.foxglove_ws import foxglove_sink_class

        return foxglove_sink_class()(config, metadata, attachments, threaded=False, **options)
    return McapSink(path, config, metadata, attachments, threaded=False, **options)


def _writer_main(conn: Connection) -> None:
    """Runs McapSink's writer side on what arrives over ``conn`` until told to close or
    the pipe ends; then writes the summary and footer."""
    for sig in _CHILD_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)  # the bench process ends the run, not a signal
    yield_cpu()  # the bench process's threads have the cores first
    pin_thread(other_cpus())  # and stay off the live path's CPU
    try:
        path, config, metadata, attachments, options = conn.recv()
    except (EOFError, OSError):
        return
    sink = _make_sink(path, config, metadata, attachments, options)
    with contextlib.suppress(OSError):
        conn.send(("status", _writer_status(sink)))
    group_s = WRITER_GROUP_S
    pending: list[Any] = []  # received items not yet encoded
    since = 0.0  # when the bench process took the first of them
    done = False
    while not done:
        deadline = since + group_s if pending else math.inf
        if sink._chunk_opened is not None:
            deadline = min(deadline, sink._chunk_opened + sink.flush_interval_s)
        wait = 0.5 if deadline == math.inf else max(0.0, deadline - time.monotonic())
        try:
            msg = conn.recv() if conn.poll(wait) else None
        except (EOFError, OSError):
            msg = ("close",)  # the bench process is gone: finish the file with what arrived
        if msg is not None and msg[0] == "close":
            done = True
        elif msg is not None and msg[0] == "items":
            if not pending:
                since = msg[2]
            pending += _unpack_items(msg[1])
            sink.dropped = msg[3]
        if pending and (done or time.monotonic() >= since + group_s):
            try:
                sink.encode_items(pending, since)
            except Exception as exc:
                sink.fail(exc)
            pending = []
            with contextlib.suppress(OSError):
                conn.send(("status", _writer_status(sink)))
        if sink._chunk_opened is not None and (
            time.monotonic() - sink._chunk_opened >= sink.flush_interval_s
        ):
            sink.flush_chunks()
    sink.finish()
    with contextlib.suppress(OSError):
        conn.send(("closed", _writer_status(sink)))


# -- the bench process's side ----------------------------------------------------------------
def viewer_warning(counts: Mapping[str, int]) -> str:
    """The end-of-run line for what slow Foxglove viewers cost ("" when nothing)."""
    from bench.mcaplog.foxglove_front import MAX_CLIENTS, SEND_TIMEOUT_S

    dropped, cut = counts.get("messages_dropped", 0), counts.get("clients_cut", 0)
    refused = counts.get("clients_refused", 0)
    parts = []
    if dropped:
        parts.append(f"{dropped} messages dropped for viewers that fell behind")
    if cut:
        parts.append(
            f"{cut} viewer{'s' if cut > 1 else ''} disconnected "
            f"(did not take what was sent within {SEND_TIMEOUT_S:g} s)"
        )
    if refused:
        parts.append(
            f"{refused} connection{'s' if refused > 1 else ''} refused "
            f"({MAX_CLIENTS} viewers were being served)"
        )
    return "; ".join(parts) + " (the run and its log are not affected)" if parts else ""


class McapProcessSink(QueuedSink):
    """McapSink's interface (a Sink: ``write``, ``mark``, ``close``, ``status``) with the
    encoding in a writer process. ``write`` only enqueues (bounded; a full queue drops the
    step and counts its frames in ``dropped``); a sender thread ships groups to the writer
    process every ``group_interval_s``."""

    def __init__(
        self,
        path: str | Path,
        config: Config,
        metadata: Mapping[str, str] | None = None,
        attachments: Sequence[tuple[str, bytes]] = (),
        *,
        queue_size: int = 10_000,
        group_interval_s: float = DEFAULT_GROUP_INTERVAL_S,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        **options: Any,
    ) -> None:
        super().__init__(path, config, queue_size, flush_interval_s, group_interval_s)
        # the live Foxglove stream is no log: its failures are the runner's output errors
        # (and a server that cannot start is the caller's one-line error), never "MCAP log"
        self._is_log = options.get("sink", "mcap") == "mcap"
        self.frames_sent = 0  # frames handed to the writer process
        self.port: int | None = None  # a live Foxglove stream's port (from the writer)
        self.viewer_counts: dict[str, int] = {}  # what slow viewers cost (the live stream)
        self._host = options.get("host", "")  # the live stream's address (its warnings)
        options = dict(options, flush_interval_s=flush_interval_s)
        # a session of its own: a terminal's Ctrl-C or hang-up is the bench process's to handle
        self._conn, self._proc = start_child(
            "bench.mcaplog.writer_process", own_session=True, quiet=True
        )
        self._gone = False
        with contextlib.suppress(OSError):
            self._conn.send(
                (str(self.path), config, dict(metadata or {}), list(attachments), options)
            )
        self._await_first()
        thread = self._thread = threading.Thread(
            target=self._run, name=f"mcap-sender:{self.path.name}", daemon=True
        )
        thread.start()
        atexit.register(self.close)

    def close(self) -> None:
        """Send what is queued, let the writer process finish the file, reap it."""
        if not self._stop_thread():
            return
        with contextlib.suppress(OSError):
            self._conn.close()
        end_child(self._proc, 10.0)
        if warning := viewer_warning(self.viewer_counts):
            log.warning("Foxglove live stream on %s: %s", self._stream_label(), warning)

    def _stream_label(self) -> str:
        """The live stream's address with its bound port (``self.path`` is a Path, which
        folds ``ws://`` to ``ws:/``, and holds the port asked for, perhaps 0)."""
        from bench.mcaplog.foxglove_ws import stream_label

        return stream_label(str(self._host), self.port if self.port is not None else 0)

    # -- sender thread ---------------------------------------------------------------------
    def _await_first(self) -> None:
        """Wait for the writer's first status (file opened, or its error)."""
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self._conn.poll(0.2):
            if self._proc.poll() is not None or time.monotonic() > deadline:
                self._lost_writer("did not start")
                return
        self._take_replies(0.0)

    def _take(self, status: dict[str, Any]) -> None:
        if status.get("port") is not None:
            self.port = int(status["port"])  # the live stream's bound port
        self.viewer_counts = dict(status.get("viewers") or self.viewer_counts)
        self.frames_logged = int(status["frames_logged"])
        self.bytes_written = int(status["bytes_written"])
        self.frames_lost = max(self.frames_lost, int(status["frames_lost"]))
        self.errors = max(self.errors, int(status["errors"]))
        if status["error"] and self.error is None:
            self.error = str(status["error"])
            if self._is_log:
                log.error(
                    "MCAP log FAILED: %s -- nothing more is logged to it (frames counted as lost)",
                    self.error,
                )

    def _take_replies(self, timeout: float) -> str | None:
        """Mirror every status the writer sent; the last reply's kind (None: none)."""
        kind = None
        try:
            while not self._gone and self._conn.poll(timeout):
                kind, status = self._conn.recv()
                self._take(status)
                timeout = 0.0
                if kind == "closed":
                    break
        except (EOFError, OSError):
            self._lost_writer("ended unexpectedly")
        return kind

    def _lost_writer(self, what: str) -> None:
        if self._gone:
            return
        self._gone = True
        with contextlib.suppress(subprocess.TimeoutExpired):
            self._proc.wait(1.0)
        self.errors += 1
        if self.error is None:
            code = self._proc.returncode
            kind = "MCAP writer" if self._is_log else "Foxglove stream's"
            self.error = f"{self.path}: the {kind} process {what} (exit code {code})"
            if self._is_log:
                log.error("MCAP log %s FAILED: writer process %s", self.path, what)
        # what was handed over and not written is lost; what comes next is counted below
        self.frames_lost = max(self.frames_lost, self.frames_sent - self.frames_logged)

    def _collect(self) -> list[Any]:
        """The next group: the first item (waiting at most a quarter second, so replies are
        read while the source is silent), then, after ``group_interval_s``, all queued."""
        try:
            items = [self._queue.get(timeout=0.25)]
        except queue.Empty:
            return []
        if items[0] is not STOP and self._queue.qsize() < MAX_GROUP:
            time.sleep(self.group_interval_s)
        return self._drain(items)

    def _run(self) -> None:
        while True:
            items = self._collect()
            stop = bool(items) and items[-1] is STOP
            if stop:
                items.pop()
            if items:
                self._send(items)
            self._take_replies(0.0)
            if stop:
                break
        if not self._gone:
            with contextlib.suppress(OSError):
                self._conn.send(("close",))
            deadline = time.monotonic() + CLOSE_TIMEOUT_S
            while not self._gone and time.monotonic() < deadline:
                if self._take_replies(0.5) == "closed":
                    return
                if self._proc.poll() is not None and not self._conn.poll(0):
                    self._lost_writer("ended before finishing the file")
            self._lost_writer("did not finish the file in time")

    def _send(self, items: list[Any]) -> None:
        frames = sum(len(item[0].frames) for item in items if item[0] != "mark")
        if self._gone:
            self.frames_lost += frames
            return
        try:
            self._conn.send(("items", _pack_items(items), time.monotonic(), self.dropped))
            self.frames_sent += frames
        except (OSError, ValueError):
            self._lost_writer("ended unexpectedly")
            self.frames_lost += frames


if __name__ == "__main__":  # the writer process (devices.child_process.start_child)
    _writer_main(parent_connection(sys.argv))
