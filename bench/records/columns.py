"""Results as Arrow columns: names with units, one schema for every writer.

The column layout is derived from the numpy dtypes (``RESULT_DTYPE`` and friends) and a table of
names and units below, so a field added to a dtype becomes a column without touching the
writers (``tests/test_columns.py`` insists that it has a unit entry). A sub-array field
(``acc``: three channels) becomes one column per element (``a1_mps2``, ``a2_mps2``, ...).

Conventions, the same in CSV and Parquet:

* a column name ends in its unit where it has one (``_s``, ``_mps2``, ``_permil``); the unit is
  also in each Parquet field's metadata (``unit``, ``description``);
* a float NaN (not computable, channel not usable) is a null: an empty CSV cell;
* booleans are Arrow booleans (written 0/1 in CSV), integers stay integers (``excluded`` is 0
  for none, else the channel 1..3);
* ``utc`` beside ``time_s``: the receive time as a UTC timestamp where the source stamps
  frames with wall-clock time (a receive time after 2000-01-01 is taken as Unix time), else
  null (emulator files and logs with relative times).

:func:`results_from_table` turns a table back into ``RESULT_DTYPE`` rows, bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from bench.records.results import RESULT_DTYPE, UNIX_TIME_FROM

UTC_COLUMN = "utc"


@dataclass(frozen=True, slots=True)
class Column:
    """One output column: where its values come from and what they mean."""

    name: str
    field: str  # dtype field
    index: int | None  # element of a sub-array field, else None
    unit: str  # "" for counts, flags and indices
    description: str


# field -> (column names, one per element for a sub-array field; unit; description)
RESULT_FIELDS: dict[str, tuple[tuple[str, ...], str, str]] = {
    "time_s": (("time_s",), "s", "board time from the first sample"),
    "n": (("counter",), "", "unwrapped sample index (the board's sample counter)"),
    "acc": (
        ("a1_mps2", "a2_mps2", "a3_mps2"),
        "m/s^2",
        "calibrated acceleration per channel; null where the channel is not usable",
    ),
    "slopes": (
        ("g12_permil", "g23_permil", "g13_permil"),
        "permil",
        "pair gradients of the reference method; null where not computable",
    ),
    "votes": (("v1", "v2", "v3"), "", "two-out-of-three votes of the reference method"),
    "weights": (("w12", "w23", "w13"), "1", "weights of the pair gradients in the result"),
    "gradient": (("gradient_permil",), "permil", "reference result; null when invalid"),
    "valid": (("valid",), "", "the reference result is valid"),
    "gradient_signed": (
        ("gradient_signed_permil",),
        "permil",
        "the bench estimator's signed gradient; null when withheld (sigma above the limit)",
    ),
    "a_ref": (
        ("a_ref_mps2",),
        "m/s^2",
        "reference acceleration from SPEED_REF; null when unavailable",
    ),
    "residual": (("residual_mps2",), "m/s^2", "least-squares residual of the estimator"),
    "degraded": (("degraded",), "", "the estimate comes from two channels only"),
    "excluded": (("excluded",), "", "channel excluded by the estimator (1..3), 0 = none"),
    "gradient_sigma": (
        ("gradient_sigma_permil",),
        "permil",
        "1-sigma of the estimator's gradient (given also while the gradient is withheld)",
    ),
    "gradient_smoothed": (
        ("gradient_smoothed_permil",),
        "permil",
        "the explicit model's gradient smoothed over the whole log (RTS, `replay --smooth`); "
        "null when withheld (sigma above the limit) or fewer than two channels",
    ),
    "gradient_smoothed_sigma": (
        ("gradient_smoothed_sigma_permil",),
        "permil",
        "1-sigma of the smoothed gradient (given also while it is withheld)",
    ),
    "odometer_suspect": (
        ("odometer_suspect",),
        "",
        "SPEED_REF rejected by the estimator's innovation gate (slip or slide)",
    ),
    "coasting": (("coasting",), "", "no SPEED_REF for coast_s: the estimator coasts"),
    "gradient_ls": (
        ("gradient_ls_permil",),
        "permil",
        "least-squares gradient magnitude (needs no a_ref)",
    ),
    "u": (("u_mps2",), "m/s^2", "specific force along the track"),
    "w": (("w_mps2",), "m/s^2", "specific force normal to the track"),
    "t": (("receive_time_s",), "s", "receive time of the sample's last frame"),
    "ticks": (("ticks",), "100 us", "unwrapped board time in board ticks"),
    "seq": (("seq",), "", "arrival index of the sample's last frame"),
    "code": (("code1", "code2", "code3"), "LSB", "raw ADC codes (0 where absent)"),
    "status": (("status1", "status2", "status3"), "", "status bytes per channel"),
    "present": (("present1", "present2", "present3"), "", "a frame of the channel joined"),
}
"""Names, units and meaning of the result fields, in output order (the analyst's columns
first); RESULT_DTYPE fields not listed follow in dtype order, named as the field."""


def columns_of(dtype: np.dtype, table: dict[str, tuple[tuple[str, ...], str, str]]) -> list[Column]:
    """The output columns of ``dtype``: the table's fields in table order, then the rest."""
    assert dtype.names is not None
    order = [f for f in table if f in dtype.names] + [f for f in dtype.names if f not in table]
    out: list[Column] = []
    for fname in order:
        sub = dtype[fname]
        width = int(np.prod(sub.shape)) if sub.shape else 0
        names, unit, doc = table.get(fname, ((), "", ""))
        if width:
            names = names if len(names) == width else tuple(f"{fname}{k + 1}" for k in range(width))
            out += [Column(nm, fname, k, unit, doc) for k, nm in enumerate(names)]
        else:
            out.append(Column(names[0] if names else fname, fname, None, unit, doc))
    return out


def _arrow_type(dt: np.dtype) -> pa.DataType:
    base = dt.base if dt.shape else dt
    return pa.bool_() if base == np.bool_ else pa.from_numpy_dtype(base)


class Layout:
    """The Arrow schema of one numpy record dtype and the conversion of its rows."""

    def __init__(
        self,
        dtype: np.dtype,
        table: dict[str, tuple[tuple[str, ...], str, str]],
        *,
        utc_after: str | None = None,
        metadata: dict[str, str] | None = None,
    ) -> None:
        self.dtype = dtype
        self.columns = columns_of(dtype, table)
        self.utc_after = utc_after  # the column the UTC timestamp goes beside
        fields = []
        self.aligned: list[Column | None] = []  # per schema field; None for the UTC column
        for col in self.columns:
            self.aligned.append(col)
            meta = {"unit": col.unit, "description": col.description}
            kind = _arrow_type(dtype[col.field])
            fields.append(pa.field(col.name, kind, metadata=meta))
            if col.name == utc_after:
                meta = {"unit": "UTC", "description": "receive time as UTC, where it is wall time"}
                fields.append(pa.field(UTC_COLUMN, pa.timestamp("us", tz="UTC"), metadata=meta))
                self.aligned.append(None)
        self.schema = pa.schema(fields, metadata=metadata)

    def with_metadata(self, metadata: dict[str, str]) -> Layout:
        """The same layout, its schema carrying file-level ``metadata``."""
        other = object.__new__(Layout)
        other.__dict__.update(self.__dict__)
        other.schema = self.schema.with_metadata(metadata)
        return other

    @property
    def names(self) -> list[str]:
        names: list[str] = self.schema.names
        return names

    def batch(self, rows: np.ndarray, schema: pa.Schema | None = None) -> pa.RecordBatch:
        """``rows`` (of this layout's dtype) as one record batch; NaN floats become nulls.

        ``schema``: only its columns (some of this layout's, in the layout's order), a
        boolean one as ``uint8`` 0/1 where it says so (the CSV's: :func:`csv_schema`,
        bench.sinks.tables), made from the rows as such: no column is built only to be
        dropped or cast."""
        if schema is None:
            schema = self.schema
        wanted = {f.name: f.type for f in schema}
        arrays: list[pa.Array] = []
        for f, col in zip(self.schema, self.aligned, strict=True):
            kind = wanted.get(f.name)
            if kind is None:
                continue
            if col is None:  # the UTC column
                arrays.append(utc_array(rows["t"]))
                continue
            x = rows[col.field] if col.index is None else rows[col.field][:, col.index]
            if x.dtype == np.bool_ and kind == pa.uint8():
                arrays.append(arrow_array(x.view(np.uint8) != 0, kind))  # 0/1 bytes
                continue
            x = np.ascontiguousarray(x)  # one pass over the rows' stride, then contiguous
            nulls = np.isnan(x) if x.dtype.kind == "f" else None
            arrays.append(arrow_array(x, kind, nulls))
        return pa.RecordBatch.from_arrays(arrays, schema=schema)

    def rows(self, table: pa.Table | pa.RecordBatch) -> np.ndarray:
        """The rows of ``table`` (written by :meth:`batch`) back as this layout's dtype;
        nulls in float columns become NaN."""
        out = np.zeros(table.num_rows, dtype=self.dtype)
        for col in self.columns:
            values = table.column(col.name)
            if isinstance(values, pa.ChunkedArray):
                values = values.combine_chunks()
            target = out[col.field] if col.index is None else out[col.field][:, col.index]
            if target.dtype.kind == "f":
                target[...] = values.to_numpy(zero_copy_only=False)  # nulls -> NaN
            else:
                target[...] = values.to_numpy(zero_copy_only=False)
        return out


def arrow_array(x: np.ndarray, kind: pa.DataType, nulls: np.ndarray | None = None) -> pa.Array:
    """The values of a 1-D numpy array as an Arrow array of ``kind`` (null where ``nulls``),
    made from its buffers: ``pa.array`` imports pandas where it is installed (0.3-0.9 s,
    in a replay's CSV writer thread, beside the pipeline)."""
    validity = None
    null_count = 0
    if nulls is not None and (null_count := int(np.count_nonzero(nulls))):
        validity = pa.py_buffer(np.packbits(~nulls, bitorder="little"))
    if x.dtype == np.bool_ and kind == pa.bool_():
        data = pa.py_buffer(np.packbits(x, bitorder="little"))
    else:
        data = pa.py_buffer(np.ascontiguousarray(x))
    return pa.Array.from_buffers(kind, len(x), [validity, data], null_count=null_count)


def utc_array(t: np.ndarray) -> pa.Array:
    """Receive times (s) as UTC microsecond timestamps; null where they are not Unix time."""
    wall = np.isfinite(t) & (t >= UNIX_TIME_FROM)
    us = np.zeros(len(t), dtype=np.int64)
    us[wall] = np.round(t[wall] * 1e6).astype(np.int64)
    return arrow_array(us, pa.timestamp("us", tz="UTC"), ~wall)


RESULTS = Layout(RESULT_DTYPE, RESULT_FIELDS, utc_after="time_s")
"""The results' columns: what `bench replay --parquet`, `bench log export --parquet` and
`bench fleet`'s dataset hold."""

CSV_LEFT_OUT = frozenset(
    {"t", "ticks", "seq", "code", "status", "present", "gradient_ls", "u", "w"}
)
"""Result fields the CSV leaves out (raw codes and the estimator's internals: in the Parquet
file); every other field, new ones included, is a CSV column."""


def csv_schema(layout: Layout) -> pa.Schema:
    """The CSV columns of a results layout: its Parquet columns less :data:`CSV_LEFT_OUT`."""
    return pa.schema(
        [f for f, c in zip(layout.schema, layout.aligned, strict=True)
         if c is None or c.field not in CSV_LEFT_OUT],
        metadata=layout.schema.metadata,
    )  # fmt: skip


CSV_SCHEMA = csv_schema(RESULTS)
"""The results CSV's columns (in the Parquet file's order)."""


def results_from_table(table: pa.Table | pa.RecordBatch) -> np.ndarray:
    """RESULT_DTYPE rows from a table of :data:`RESULTS` columns (a read-back Parquet file)."""
    return RESULTS.rows(table)
