"""Results written as CSV or Parquet by pyarrow, in a thread of their own behind a bounded hand-off.

Why a thread: turning floats into shortest round-trip text and compressing Parquet pages is
most of the cost of an output, and pyarrow does both without the GIL, so they overlap the
pipeline. Why bounded: a replay must not hold all its results at once (the producer waits
when ``max_pending_rows`` are queued), and a live run must never wait on a disk (the rows
that do not fit are counted as lost instead).

Files (:class:`CsvFile`, :class:`ParquetFile`) write whole Arrow tables; :class:`TableSink`
is the pipeline-facing :class:`bench.sinks.Sink` that batches rows for them. A write that
fails (disk full, a broken device) does not raise in the pipeline: the sink keeps the
first error in ``error`` (one line naming the file), drops what follows and counts it in
``rows_lost``; the replay turns that into ``bench: error:`` and exit 2, a live run into an
event, a status-line flag and a non-zero exit while the MCAP log goes on.

A file is written under a temporary name beside the real one (:class:`devices.paths.
StagedFile`) and renamed into place by :meth:`TableSink.close` only when complete and
without a failure; a failed or aborted output is removed, so the real name never holds
half a file. A live run's file that is deleted or replaced while it is written, or whose
real name becomes a folder, is a write failure like a full disk.
"""

from __future__ import annotations

import contextlib
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq

from bench.records.columns import CSV_SCHEMA, RESULTS, Layout, csv_schema
from bench.sinks.base import Sink
from bench.sinks.paths import STDOUT, check_output_file, describe_os_error
from devices.paths import StagedFile, stageable

if TYPE_CHECKING:
    from bench.config import Config

CSV_CHUNK_ROWS = 65_536
"""Rows per CSV write in a replay (one Arrow conversion per chunk)."""
PARQUET_ROW_GROUP = 65_536
"""Rows per Parquet row group: large enough for zstd and column statistics to pay off (the
file is 0.3 % larger than with 262 144), small enough that a replay's groups are encoded
behind its pipeline and the last one, written after the pipeline ends, is short."""
TAKE_ROWS = 32_768
"""A replay hands rows to the writer in about this many at a time (and waits when twice as
many are queued): the bound on the results a replay holds besides one chunk."""
LIVE_INTERVAL_S = 0.5
"""A live run's CSV is written this often: the writer wakes on a timer, not per step, so it
never takes the GIL between the acquisition and processing threads' hand-offs."""
LIVE_MAX_PENDING_ROWS = 200_000
"""Rows a live CSV may fall behind (200 s at 1 kHz) before rows are counted as lost."""


def open_stream(target: str | Path) -> pa.NativeFile:
    """A pyarrow output stream for a path or ``-`` (stdout)."""
    if str(target) == STDOUT:
        return pa.PythonFile(sys.stdout.buffer, mode="w")
    return pa.OSFile(str(target), "wb")


def _csv_schema(schema: pa.Schema) -> pa.Schema:
    """Booleans as 0/1 integers (the form spreadsheets and `csv` readers expect)."""
    return pa.schema(
        [pa.field(f.name, pa.uint8()) if f.type == pa.bool_() else f for f in schema],
        metadata=schema.metadata,
    )


class TableFile(Protocol):
    path: str

    def write(self, table: pa.Table) -> None: ...

    def close(self) -> None: ...


PARALLEL_ROWS = 8192
"""Chunks of at least this many rows are turned into text by two threads, half the rows
each (pyarrow's CSV writer runs without the GIL): text is most of a CSV's cost."""


class CsvFile:
    """A CSV file of ``schema``'s columns (tables written to it may have more): a plain
    header line (the column names, each ending in its unit), then pyarrow's CSV writer:
    floats in shortest round-trip form, NaN/null as an empty cell, integers as integers,
    booleans as 0/1.

    A table of :attr:`schema` (booleans already ``uint8``: what :class:`TableSink` makes
    for it) is written as it is; another is selected and cast first (pyarrow.compute,
    about 60 ms to import). A large one is written as two halves of its rows by pyarrow's
    writer, the first into the file, the second meanwhile into a buffer by a thread of its
    own, written after it: a row's text does not depend on the rows around it, so the bytes
    are those of one writer."""

    def __init__(
        self,
        target: str | Path | pa.NativeFile,
        schema: pa.Schema = CSV_SCHEMA,
        *,
        opener: Callable[[str | Path], pa.NativeFile] | None = None,
    ) -> None:
        self.path = str(target) if not isinstance(target, pa.NativeFile) else "<stream>"
        self._own = not isinstance(target, pa.NativeFile)
        opener = opener or open_stream  # looked up now: a test may stand in a failing stream
        self._out = opener(target) if isinstance(target, str | Path) else target
        self.schema = _csv_schema(schema)
        self._out.write((",".join(schema.names) + "\n").encode())
        self._options = pa_csv.WriteOptions(include_header=False, quoting_style="none")
        self._pool: ThreadPoolExecutor | None = None

    def write(self, table: pa.Table) -> None:
        if not table.schema.equals(self.schema):
            table = table.select(self.schema.names).cast(self.schema)
        if table.num_rows < PARALLEL_ROWS:
            pa_csv.write_csv(table, self._out, self._options)
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1, thread_name_prefix="csv text")
        half = table.num_rows // 2
        second = self._pool.submit(self._text, table.slice(half))
        try:
            pa_csv.write_csv(table.slice(0, half), self._out, self._options)
        finally:
            text = second.result()  # not left running after a failure
        self._out.write(text)

    def _text(self, table: pa.Table) -> pa.Buffer:
        out = pa.BufferOutputStream()
        pa_csv.write_csv(table, out, self._options)
        return out.getvalue()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
        if self._own:
            self._out.close()
        else:
            self._out.flush()


class ParquetFile:
    """A Parquet file of one layout, zstd-compressed, one row group per :meth:`write`; units
    in the field metadata, what the file holds (calibration, source) in the file metadata.

    Plain encoding, no dictionary: the float columns (most of the file) hardly ever repeat
    a value, so a dictionary was built for each and thrown away, and zstd packs the few
    constant columns as well without it (the file is smaller): 60 % less encoding CPU."""

    def __init__(
        self,
        target: str | Path | pa.NativeFile,
        schema: pa.Schema = RESULTS.schema,
        metadata: dict[str, str] | None = None,
        *,
        opener: Callable[[str | Path], pa.NativeFile] | None = None,
    ) -> None:
        self.path = str(target) if not isinstance(target, pa.NativeFile) else "<stream>"
        self._own = not isinstance(target, pa.NativeFile)
        opener = opener or open_stream  # looked up now: a test may stand in a failing stream
        self._out = opener(target) if isinstance(target, str | Path) else target
        if metadata:
            schema = schema.with_metadata({**(schema.metadata or {}), **metadata})
        self._writer = pq.ParquetWriter(self._out, schema, compression="zstd", use_dictionary=False)

    def write(self, table: pa.Table) -> None:
        self._writer.write_table(table, row_group_size=max(1, table.num_rows))

    def close(self) -> None:
        try:
            self._writer.close()
        finally:
            if self._own:
                self._out.close()


def results_csv_text(results: np.ndarray) -> str:
    """``results`` as the text of a results CSV (what `bench replay --csv` writes)."""
    out = pa.BufferOutputStream()
    f = CsvFile(out)
    if len(results):
        f.write(pa.Table.from_batches([RESULTS.batch(results)]))
    f.close()
    return out.getvalue().to_pybytes().decode()


class TableSink(Sink):
    """Pipeline results -> a :class:`TableFile`, written by a thread of its own.

    ``live=False`` (a replay): the producer waits while ``max_pending_rows`` are queued, and
    the writer works in chunks of ``chunk_rows``. ``live=True``: the producer never waits
    (rows beyond the bound are lost and counted) and the writer wakes every
    :data:`LIVE_INTERVAL_S`. ``raise_errors``: :meth:`write` raises the first write failure
    (a replay stops at once); otherwise it is only kept in :attr:`error`. ``columns``: the
    layout's columns the file takes, as it takes them (a CSV's: :attr:`CsvFile.schema`),
    the only ones made of the rows; None: every column."""

    def __init__(
        self,
        file: TableFile,
        layout: Layout = RESULTS,
        *,
        live: bool = False,
        chunk_rows: int = CSV_CHUNK_ROWS,
        max_pending_rows: int | None = None,
        raise_errors: bool = False,
        cpus: frozenset[int] | None = None,
        kind: str = "CSV",
        staged: StagedFile | None = None,
        columns: pa.Schema | None = None,
    ) -> None:
        self.file = file
        self.columns = columns  # of the layout's columns, those the file takes (all: None)
        self.staged = staged  # the temporary name the file is written under, if any
        self.path = str(staged.path) if staged is not None else file.path
        self.kept = True  # False once a staged file was removed (failed or aborted)
        self.kind = kind
        self.layout = layout
        self.live = live
        self.chunk_rows = chunk_rows
        self.take_rows = min(chunk_rows, TAKE_ROWS)
        self.max_pending_rows = max_pending_rows or (
            LIVE_MAX_PENDING_ROWS if live else 2 * self.take_rows
        )
        self.raise_errors = raise_errors
        self.rows = 0  # rows written
        self._lost_put = 0  # rows refused by put() (counted by the producer)
        self._lost_write = 0  # rows the writer could not write (counted by the writer)
        self.error: str | None = None
        self.errno = 0  # of the first failure, when it was an OSError
        self.broken_pipe = False
        self._cpus = cpus
        self._pending: list[np.ndarray] = []
        self._pending_rows = 0
        self._closing = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._run, name=f"{kind} writer", daemon=True)
        self._thread.start()

    @property
    def rows_lost(self) -> int:
        """Rows not written: after a failure, or beyond a live run's bound."""
        return self._lost_put + self._lost_write

    # -- producer side (the pipeline's thread) ------------------------------------------------
    def write(self, step: Any) -> None:
        self.put(step.results)

    def put(self, rows: np.ndarray) -> None:
        if self.error is not None:
            self._lost_put += len(rows)
            self._raise()
            return
        if len(rows) == 0:
            return
        with self._cond:
            if self.live:
                if self._pending_rows + len(rows) > self.max_pending_rows:
                    self._lost_put += len(rows)
                    return
            else:
                while self._pending_rows >= self.max_pending_rows and self.error is None:
                    self._cond.wait()
            self._pending.append(rows)
            self._pending_rows += len(rows)
            if not self.live and self._pending_rows >= self.take_rows:
                self._cond.notify_all()
        self._raise()

    def close(self) -> None:
        """Write what is queued, finish the file and rename it into place; raises the
        failure if ``raise_errors`` (the file is then removed)."""
        self.finish()
        self.commit()
        self._raise()

    def finish(self) -> None:
        """Write what is queued and finish the file, still under its temporary name."""
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self._thread.join()

    def commit(self) -> None:
        """The finished file renamed into place; after a failure it is removed instead."""
        if self.staged is None or self.staged.done:
            return
        if self.error is not None:
            self.discard()
            return
        try:
            self.staged.commit()
        except OSError as exc:
            self.kept = False
            self._fail(exc, self.rows)

    def abort(self) -> None:
        """Finish and remove the file: another failure ends the run (nothing half-written
        stays under the real name)."""
        self.finish()
        self.discard()

    def discard(self) -> None:
        if self.staged is not None and not self.staged.done:
            self.staged.discard()
            self.kept = False

    def _raise(self) -> None:
        if self.broken_pipe and self.raise_errors:
            raise BrokenPipeError
        if self.error is not None and self.raise_errors:
            from bench.errors import BenchError

            raise BenchError(self.error)

    # -- the writer thread -------------------------------------------------------------------
    def _take(self) -> tuple[list[np.ndarray], bool]:
        """Wait for work; returns the rows to convert now and whether this is the end."""
        with self._cond:
            if self.live:
                if not self._closing:
                    self._cond.wait(LIVE_INTERVAL_S)
            else:
                while self._pending_rows < self.take_rows and not self._closing:
                    self._cond.wait()
            parts, self._pending, self._pending_rows = self._pending, [], 0
            self._cond.notify_all()  # a waiting producer may go on
            return parts, self._closing

    def _run(self) -> None:
        """Rows become Arrow batches as they arrive (as compact as the numpy rows, so a
        chunk waiting for its row group costs one copy of it); whole chunks are written.

        A replay's chunks are written behind, by an encoder thread, one at a time and in
        order: pyarrow encodes a chunk without the GIL (a Parquet row group takes a third of
        a second), and meanwhile this thread goes on taking the pipeline's rows, which
        would otherwise wait for it. A live run writes small chunks itself."""
        if self._cpus:
            from devices.cpu_placement import pin_thread

            pin_thread(self._cpus)
        encoder = None
        if not self.live:
            encoder = ThreadPoolExecutor(1, thread_name_prefix=f"{self.kind} encoder")
        writing: Future[None] | None = None
        buffered: list[pa.RecordBatch] = []
        n_buffered = 0
        try:
            while True:
                parts, end = self._take()
                if self.error is not None:
                    writing = _done(writing)  # the encoder's count first, then this one
                    self._lost_write += sum(len(p) for p in parts) + n_buffered
                    buffered, n_buffered = [], 0
                else:
                    for rows in parts:
                        try:
                            buffered.append(self.layout.batch(rows, self.columns))
                            n_buffered += len(rows)
                        except Exception as exc:
                            self._fail(exc, len(rows))
                    while n_buffered >= self.chunk_rows or (n_buffered and (end or self.live)):
                        table = pa.Table.from_batches(buffered)
                        take = min(self.chunk_rows, n_buffered)
                        writing = _done(writing)
                        if encoder is None:
                            self._write(table.slice(0, take))
                        else:
                            writing = encoder.submit(self._write, table.slice(0, take))
                        rest = table.slice(take)
                        buffered, n_buffered = rest.to_batches(), rest.num_rows
                if end:
                    break
                staged = self.staged if self.live and self.error is None else None
                if staged is not None and (why := staged.problem()):
                    self._fail(OSError(why), 0)  # like a full disk: the rows go nowhere
        finally:
            _done(writing)
            if encoder is not None:
                encoder.shutdown()
        try:
            self.file.close()
        except Exception as exc:  # the last bytes and the footer can fail too
            self._fail(exc, 0)

    def _write(self, table: pa.Table) -> None:
        if self.error is not None:
            self._lost_write += table.num_rows
            return
        try:
            self.file.write(table)
            self.rows += table.num_rows
        except Exception as exc:
            self._fail(exc, table.num_rows)

    def _fail(self, exc: Exception, rows: int) -> None:
        self._lost_write += rows
        if isinstance(exc, BrokenPipeError):
            self.broken_pipe = True
        if self.error is None:
            why = describe_os_error(exc) if isinstance(exc, OSError) else repr(exc)
            self.errno = (exc.errno or 0) if isinstance(exc, OSError) else 0
            self.error = f"{self.path}: cannot write the {self.kind}: {why}"
        with self._cond:
            self._cond.notify_all()

    def status(self) -> dict[str, Any]:
        return {
            "path": self.path,
            "kind": self.kind,
            "rows": self.rows,
            "rows_lost": self.rows_lost,
            "error": self.error,
            "kept": self.kept,
        }


def _done(writing: Future[None] | None) -> Future[None] | None:
    """Wait for the write under way, if any (:meth:`TableSink._write` keeps its failure);
    None: no write is under way any more."""
    if writing is not None:
        writing.result()
    return None


def csv_sink(
    target: str | Path,
    *,
    live: bool = False,
    raise_errors: bool | None = None,
    layout: Layout = RESULTS,
    **kw: Any,
) -> TableSink:
    """The results CSV of a replay (``live=False``) or a live run, path checked first;
    ``layout``: the rows' layout (bench.replay.model_columns.LAYOUT for --smooth)."""
    check_output_file(target, "CSV")
    cpus = None
    if live:
        from devices.cpu_placement import other_cpus

        cpus = other_cpus()
    staged = StagedFile(target) if stageable(target) else None
    if layout is not RESULTS:
        kw["schema"] = csv_schema(layout)
    file = _open(CsvFile, target, "CSV", staged, **kw)
    return TableSink(
        file,
        layout,
        columns=file.schema,
        live=live,
        raise_errors=not live if raise_errors is None else raise_errors,
        cpus=cpus,
        kind="CSV",
        staged=staged,
    )


def parquet_sink(
    target: str | Path,
    metadata: dict[str, str] | None = None,
    *,
    layout: Layout = RESULTS,
    **kw: Any,
) -> TableSink:
    """The results Parquet file of a replay, path checked first (``layout``: as for
    :func:`csv_sink`)."""
    check_output_file(target, "Parquet file")
    staged = StagedFile(target) if stageable(target) else None
    return TableSink(
        _open(
            ParquetFile,
            target,
            "Parquet file",
            staged,
            schema=layout.schema,
            metadata=metadata,
            **kw,
        ),
        layout,
        chunk_rows=PARQUET_ROW_GROUP,
        raise_errors=True,
        kind="Parquet file",
        staged=staged,
    )


def close_all(sinks: list[TableSink]) -> None:
    """Finish every file, then rename them all into place; when one failed, every one is
    removed and the first failure raised (a replay's outputs are whole or absent)."""
    for sink in sinks:
        sink.finish()
    failed = next((s for s in sinks if s.error is not None or s.broken_pipe), None)
    for sink in sinks:
        if failed is not None:
            sink.discard()
        else:
            sink.commit()
    for sink in sinks:
        sink._raise()


def abort_all(sinks: list[TableSink]) -> None:
    """Finish and remove every file after another failure, keeping quiet about their own."""
    for sink in sinks:
        with contextlib.suppress(Exception):  # the failure being raised is the one to tell
            sink.abort()


def _open(cls: type, target: str | Path, what: str, staged: StagedFile | None, **kw: Any) -> Any:
    from bench.errors import BenchError

    try:
        return cls(staged.create() if staged is not None else target, **kw)
    except OSError as exc:
        if staged is not None:
            staged.discard()
        raise BenchError(f"{target}: cannot write the {what}: {describe_os_error(exc)}") from None


def results_metadata(config: Config, source: str) -> dict[str, str]:
    """File-level metadata of a results Parquet file: the calibration (as TOML, as `--config`
    reads it) and where it came from, the source log, the bench version."""
    from bench import __version__

    return {
        "bench.version": __version__,
        "bench.source": str(source),
        "bench.calibration": config.to_toml(),
        "bench.calibration_source": config.describe(),
    }
