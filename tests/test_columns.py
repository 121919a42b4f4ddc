"""Results as columns: CSV and Parquet from pyarrow, exact floats, units, the UTC column.

Expectations are independent of the writers: Python's own float parsing and ``struct`` bit
patterns, the in-memory RESULT_DTYPE rows of the same replay, a table of units written by
hand, the receive times of the frames written into the log.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import math
import struct
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.cli import main
from bench.config import Config
from bench.records.columns import CSV_SCHEMA, RESULT_FIELDS, RESULTS, results_from_table
from bench.records.results import RESULT_DTYPE
from bench.replay.run import replay
from bench.sinks.tables import CsvFile, ParquetFile
from devices.formats import open_log
from devices.writers import write_candump
from tests.test_mcap_support import emulated

T0 = 1_764_000_000.0  # 2025-11-24T16:00:00Z: frames stamped by a wall clock


def _bits(x: float) -> int:
    return struct.unpack("<Q", struct.pack("<d", x))[0]


def _csv_bytes(table: pa.Table) -> str:
    out = pa.BufferOutputStream()
    f = CsvFile(out, table.schema)
    f.write(table)
    f.close()
    return out.getvalue().to_pybytes().decode()


def test_every_result_field_has_a_column_name_and_unit_entry():
    """A field added to RESULT_DTYPE must say its column names and unit here."""
    assert set(RESULT_DTYPE.names) <= set(RESULT_FIELDS), set(RESULT_DTYPE.names) - set(
        RESULT_FIELDS
    )
    for name in RESULT_DTYPE.names:
        sub = RESULT_DTYPE.fields[name][0]
        names = RESULT_FIELDS[name][0]
        assert len(names) == (sub.shape[0] if sub.shape else 1), name


def test_column_names_end_in_their_units():
    """The CSV header says each unit: physical columns end in it, and the Parquet field
    metadata carries the same unit (the table written by hand here, not the code's)."""
    expected = {
        "time_s": "s",
        "a1_mps2": "m/s^2",
        "a3_mps2": "m/s^2",
        "g12_permil": "permil",
        "g13_permil": "permil",
        "gradient_permil": "permil",
        "gradient_signed_permil": "permil",
        "a_ref_mps2": "m/s^2",
        "residual_mps2": "m/s^2",
        "u_mps2": "m/s^2",
        "receive_time_s": "s",
        "excluded": "",
        "valid": "",
        "counter": "",
    }
    schema = RESULTS.schema
    for name, unit in expected.items():
        assert schema.field(name).metadata[b"unit"].decode() == unit, name
    assert schema.field("excluded").type == pa.uint8()
    assert schema.field("valid").type == pa.bool_()
    assert schema.field("utc").type == pa.timestamp("us", tz="UTC")
    assert schema.names.index("utc") == schema.names.index("time_s") + 1


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.floats(allow_nan=False, allow_infinity=True, width=64),
        min_size=1,
        max_size=50,
    )
)
def test_pyarrow_csv_float_text_round_trips_float64_exactly(values):
    table = pa.table({"x": pa.array(values, type=pa.float64())})
    lines = _csv_bytes(table).splitlines()
    assert lines[0] == "x"
    back = [float(s) for s in lines[1:]]
    assert [_bits(v) for v in back] == [_bits(v) for v in values]


def test_csv_nan_is_an_empty_cell_and_integers_stay_integers():
    rows = np.zeros(3, dtype=RESULT_DTYPE)
    rows["n"] = [7, 8, 2**40]
    rows["gradient"] = [1.5, np.nan, -0.0]
    rows["excluded"] = [0, 3, 1]
    rows["valid"] = [True, False, True]
    out = pa.BufferOutputStream()
    f = CsvFile(out)
    f.write(pa.Table.from_batches([RESULTS.batch(rows)]))
    f.close()
    got = list(csv.DictReader(io.StringIO(out.getvalue().to_pybytes().decode())))
    assert [r["counter"] for r in got] == ["7", "8", "1099511627776"]
    assert [r["gradient_permil"] for r in got] == ["1.5", "", "-0"]
    assert [r["excluded"] for r in got] == ["0", "3", "1"]
    assert [r["valid"] for r in got] == ["1", "0", "1"]
    assert [r["utc"] for r in got] == ["", "", ""]  # receive time 0: not wall time


def _replay_outputs(tmp_path: Path, log: Path) -> tuple[np.ndarray, Path, Path]:
    out_csv, out_pq = tmp_path / "r.csv", tmp_path / "r.parquet"
    assert main(["replay", str(log), "--csv", str(out_csv), "--parquet", str(out_pq), "-q"]) == 0
    source = open_log(str(log))
    try:
        memory = replay(source, Config()).results
    finally:
        source.close()
    return memory, out_csv, out_pq


@pytest.fixture(scope="module")
def wall_clock_log(tmp_path_factory) -> Path:
    """A faulty emulated run written as candump with wall-clock receive times."""
    sim = emulated(15.0)
    frames = sim.frames.copy()
    frames["t"] = np.round((frames["t"] + T0) * 1e6) / 1e6
    path = tmp_path_factory.mktemp("cols") / "wall.log"
    write_candump(path, frames)
    return path


def test_csv_and_parquet_of_one_replay_equal_the_in_memory_results_bit_for_bit(
    tmp_path, wall_clock_log
):
    memory, out_csv, out_pq = _replay_outputs(tmp_path, wall_clock_log)
    assert len(memory) > 1000
    assert np.isnan(memory["gradient"]).any() and (memory["excluded"] > 0).any()
    table = pq.read_table(out_pq)
    assert table.num_rows == len(memory)
    assert results_from_table(table).tobytes() == memory.tobytes()

    rows = list(csv.DictReader(out_csv.open()))
    assert len(rows) == len(memory)
    assert list(rows[0]) == CSV_SCHEMA.names
    columns = table.to_pydict()
    for col in RESULTS.columns:
        if col.name not in CSV_SCHEMA.names:
            assert col.field in ("t", "ticks", "seq", "code", "status", "present", "u", "w",
                                 "gradient_ls"), col.name  # fmt: skip
            continue
        values = memory[col.field] if col.index is None else memory[col.field][:, col.index]
        cells = [r[col.name] for r in rows]
        if values.dtype.kind == "f":
            from_csv = [math.nan if c == "" else float(c) for c in cells]
            assert [_bits(v) for v in from_csv] == [_bits(v) for v in values.tolist()], col.name
            from_pq = [math.nan if v is None else v for v in columns[col.name]]
            assert [_bits(v) for v in from_pq] == [_bits(v) for v in values.tolist()], col.name
        else:
            assert [int(c) for c in cells] == [int(v) for v in values.tolist()], col.name
            assert [int(v) for v in columns[col.name]] == [int(v) for v in values.tolist()]


def test_utc_column_is_the_wall_clock_receive_time(tmp_path, wall_clock_log):
    memory, out_csv, out_pq = _replay_outputs(tmp_path, wall_clock_log)
    utc = pq.read_table(out_pq, columns=["utc"]).column("utc").to_pylist()
    epoch = dt.datetime(1970, 1, 1, tzinfo=dt.UTC)
    for k in (0, len(memory) // 2, len(memory) - 1):
        assert utc[k] == epoch + dt.timedelta(microseconds=round(float(memory["t"][k]) * 1e6))
    assert utc[0].year == 2025 and utc[0].month == 11 and utc[0].day == 24
    cell = next(csv.DictReader(out_csv.open()))["utc"]
    assert cell.startswith("2025-11-24 16:00:") and cell.endswith("Z")


def test_parquet_says_units_calibration_and_source_in_its_schema(tmp_path, wall_clock_log):
    cal = tmp_path / "cal.toml"
    cal.write_text("[[channels]]\nangle_deg = 30.5\n[[channels]]\nangle_deg = 0.1\n"
                   "[[channels]]\nangle_deg = -29.5\n")  # fmt: skip
    out = tmp_path / "c.parquet"
    args = ["replay", str(wall_clock_log), "--config", str(cal), "--parquet", str(out), "-q"]
    assert main(args) == 0
    schema = pq.read_schema(out)
    meta = {k.decode(): v.decode() for k, v in schema.metadata.items()}
    assert "angle_deg = 30.5" in meta["bench.calibration"]
    assert meta["bench.source"] == str(wall_clock_log)
    assert schema.field("g23_permil").metadata[b"unit"] == b"permil"
    group = pq.ParquetFile(out).metadata.row_group(0)
    assert group.column(0).compression == "ZSTD"
    # plain pages: no column carries a dictionary (RESULTS.md says why)
    assert not any(group.column(i).has_dictionary_page for i in range(group.num_columns))


def test_parquet_row_groups_are_bounded(tmp_path):
    rows = np.zeros(2500, dtype=RESULT_DTYPE)
    rows["n"] = np.arange(2500)
    from bench.sinks.tables import TableSink

    out = tmp_path / "g.parquet"
    sink = TableSink(ParquetFile(out), chunk_rows=1000, raise_errors=True)
    for i in range(0, 2500, 300):
        sink.put(rows[i : i + 300])
    sink.close()
    f = pq.ParquetFile(out)
    assert [f.metadata.row_group(i).num_rows for i in range(f.num_row_groups)] == [1000, 1000, 500]
    assert f.read().column("counter").to_pylist() == list(range(2500))


class _HeldFile:
    """A results file whose first write waits until the test lets it go (a row group being
    compressed); every write's rows are kept, in order."""

    path = "<held>"

    def __init__(self) -> None:
        import threading

        self.started, self.release = threading.Event(), threading.Event()
        self.timed_out = False
        self.written: list[int] = []
        self.closed = False

    def write(self, table: pa.Table) -> None:
        self.started.set()
        if not self.written and not self.release.wait(timeout=30):  # never: the test hung
            self.timed_out = True
        self.written += table.column("counter").to_pylist()

    def close(self) -> None:
        self.closed = True


def test_a_replay_does_not_wait_while_a_chunk_is_written():
    """While one chunk is being written, the replay goes on handing over rows: a chunk and
    the queue's bound (4 + 8 rows here) more than while the writer itself was writing."""
    from bench.sinks.tables import TableSink

    rows = np.zeros(20, dtype=RESULT_DTYPE)
    rows["n"] = np.arange(20)
    held = _HeldFile()
    sink = TableSink(held, chunk_rows=4, max_pending_rows=8)
    sink.put(rows[:4])
    assert held.started.wait(timeout=30)  # the first chunk's write is under way, held
    for i in range(4, 16, 4):  # 12 more rows fit meanwhile
        sink.put(rows[i : i + 4])
    held.release.set()
    sink.put(rows[16:])
    sink.close()
    assert not held.timed_out  # the puts above returned while the first write was held
    assert held.written == list(range(20))
    assert held.closed and sink.rows == 20 and sink.rows_lost == 0


def test_a_failed_write_behind_counts_every_row_after_it():
    from bench.sinks.tables import TableSink

    class Full(_HeldFile):
        def write(self, table: pa.Table) -> None:
            if self.written:
                raise OSError(28, "No space left on device")
            self.written += table.column("counter").to_pylist()

    rows = np.zeros(40, dtype=RESULT_DTYPE)
    rows["n"] = np.arange(40)
    full = Full()
    sink = TableSink(full, chunk_rows=8)
    for i in range(0, 40, 4):
        sink.put(rows[i : i + 4])  # raise_errors=False: never raises, keeps the error
    sink.close()
    assert full.written == list(range(8))
    assert sink.rows == 8 and sink.rows_lost == 32
    assert sink.error == "<held>: cannot write the CSV: No space left on device"


def test_large_chunks_formatted_by_two_threads_are_exact_too():
    """Chunks of PARALLEL_ROWS or more take the two-thread path: the same exact text."""
    from bench.sinks.tables import PARALLEL_ROWS

    rng = np.random.default_rng(3)
    n = PARALLEL_ROWS * 2 + 7
    bits = rng.integers(0, 2**64, size=n, dtype=np.uint64)
    x = bits.view(np.float64)
    x = x[np.isfinite(x)]
    rows = np.zeros(len(x), dtype=RESULT_DTYPE)
    rows["residual"] = x
    rows["n"] = np.arange(len(x))
    out = pa.BufferOutputStream()
    f = CsvFile(out)
    f.write(pa.Table.from_batches([RESULTS.batch(rows)]))
    f.close()
    got = list(csv.DictReader(io.StringIO(out.getvalue().to_pybytes().decode())))
    assert [int(r["counter"]) for r in got] == list(range(len(x)))
    back = np.array([float(r["residual_mps2"]) for r in got])
    assert back.view(np.uint64).tolist() == x.view(np.uint64).tolist()


def test_a_layouts_batch_of_a_schema_makes_only_its_columns_booleans_as_0_1_bytes():
    """The CSV's batch is made of the rows as the CSV takes it: its columns only, in its
    order, a boolean as uint8 0/1 (any non-zero byte a numpy bool may hold is 1)."""
    from bench.sinks.tables import CsvFile

    rows = np.zeros(3, dtype=RESULT_DTYPE)
    rows["n"] = [5, 6, 7]
    rows["valid"].view(np.uint8)[:] = [0, 1, 2]  # a raw byte 2: still true
    rows["votes"][:, 1] = [True, False, True]
    rows["gradient"] = [0.25, np.nan, 3.0]
    rows["t"] = [T0, 0.0, T0 + 1.5]
    schema = CsvFile(pa.BufferOutputStream()).schema
    batch = RESULTS.batch(rows, schema)
    assert batch.schema.names == CSV_SCHEMA.names  # no receive_time_s, code1, u_mps2 ...
    assert batch.schema.field("valid").type == pa.uint8()
    assert batch.column("valid").to_pylist() == [0, 1, 1]
    assert batch.column("v2").to_pylist() == [1, 0, 1]
    assert batch.column("gradient_permil").to_pylist() == [0.25, None, 3.0]
    assert batch.column("counter").to_pylist() == [5, 6, 7]
    epoch = dt.datetime(1970, 1, 1, tzinfo=dt.UTC)
    assert batch.column("utc").to_pylist() == [
        epoch + dt.timedelta(seconds=T0),
        None,
        epoch + dt.timedelta(seconds=T0 + 1.5),
    ]


def test_a_large_chunk_written_in_two_halves_is_pyarrows_own_text_of_the_table():
    """Two threads each write half the rows of a chunk: the file is the header line and
    then byte for byte what pyarrow's CSV writer makes of the whole table in one call."""
    import pyarrow.csv as pa_csv

    from bench.sinks.tables import PARALLEL_ROWS

    rng = np.random.default_rng(5)
    n = PARALLEL_ROWS + 1001  # odd: the halves differ by a row
    rows = np.zeros(n, dtype=RESULT_DTYPE)
    rows["n"] = np.arange(n)
    rows["acc"] = rng.normal(size=(n, 3))
    rows["gradient"] = np.where(rng.random(n) < 0.2, np.nan, rng.normal(size=n) * 40)
    rows["valid"] = rng.random(n) < 0.5
    rows["t"] = T0 + np.arange(n) * 1e-3
    out = pa.BufferOutputStream()
    f = CsvFile(out)
    table = pa.Table.from_batches([RESULTS.batch(rows, f.schema)])
    f.write(table)
    f.close()
    whole = pa.BufferOutputStream()
    pa_csv.write_csv(table, whole)  # with pyarrow's own header line, quoted
    header, text = whole.getvalue().to_pybytes().split(b"\n", 1)
    assert header == b",".join(b'"%s"' % name.encode() for name in CSV_SCHEMA.names)
    assert out.getvalue().to_pybytes() == ",".join(CSV_SCHEMA.names).encode() + b"\n" + text


def test_a_quiet_csv_replay_imports_no_pyarrow_compute(tmp_path):
    """The CSV's columns are made as it writes them (no cast): `bench replay --csv` does not
    import pyarrow.compute (about 60 ms of a start). In a fresh interpreter."""
    import subprocess
    import sys
    import textwrap

    log = tmp_path / "board.log"
    write_candump(log, emulated(2.0, faults=False).frames)
    out = tmp_path / "r.csv"
    code = textwrap.dedent(
        f"""
        import sys
        from bench.cli import main
        assert main(["replay", {str(log)!r}, "--csv", {str(out)!r}, "-q"]) == 0
        print(sorted(m for m in sys.modules if m.startswith("pyarrow.")))
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "pyarrow.csv" in done.stdout and "pyarrow.compute" not in done.stdout
    assert len(out.read_text().splitlines()) > 100  # 2 s of 200 rows a second, and a header
