"""One row per replayed log for `bench fleet`'s ``logs.parquet``: counted while the log replays.

:class:`SummarySink` sees every pipeline step (a :class:`bench.sinks.Sink`) and keeps only
running figures (time each channel was excluded, invalid spans, the largest gap between the
reference method and the estimator), so a fleet's worth of logs costs no more memory than
one step; :func:`summary_row` adds the pipeline's own counters at the end.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np
import pyarrow as pa

from bench.pipeline.stats import Stats
from bench.records.events import EventKind
from bench.sinks.base import Sink

WORST_EVENTS = 5
"""Event kinds listed per log, most frequent first (benign kinds left out)."""
_BENIGN = {EventKind.MARK, EventKind.READMITTED, EventKind.BOARD_STATE, EventKind.RECONNECT}


class SummarySink(Sink):
    """Running figures of a replay that the pipeline's Stats do not keep."""

    def __init__(self) -> None:
        self.rows = 0
        self.excluded_s = [0.0, 0.0, 0.0]  # board time with channel k excluded
        self.invalid_spans = 0
        self.max_ref_minus_est = math.nan  # max |gradient - gradient_signed|, permil
        self.first_time_s = math.nan
        self.last_time_s = math.nan
        self._prev: tuple[float, int, bool] | None = None  # time_s, excluded, valid of the last row

    def write(self, step: Any) -> None:
        res = step.results
        if len(res) == 0:
            return
        t = res["time_s"]
        ex = res["excluded"].astype(np.int64)
        valid = res["valid"]
        if self._prev is not None:  # the step boundary: the last row's state lasts until now
            t0, ex0, valid0 = self._prev
            if 1 <= ex0 <= 3:
                self.excluded_s[ex0 - 1] += max(0.0, float(t[0]) - t0)
            starts = int(valid0 and not valid[0])
        else:
            self.first_time_s = float(t[0])
            starts = int(not valid[0])
        dt = np.maximum(np.diff(t), 0.0)  # row i's state holds until row i + 1
        for k in range(3):
            self.excluded_s[k] += float(dt[ex[:-1] == k + 1].sum())
        starts += int(np.count_nonzero(valid[:-1] & ~valid[1:]))
        self.invalid_spans += starts
        both = np.isfinite(res["gradient"]) & np.isfinite(res["gradient_signed"])
        if both.any():
            d = float(np.max(np.abs(res["gradient"][both] - res["gradient_signed"][both])))
            if not d <= self.max_ref_minus_est:  # NaN start
                self.max_ref_minus_est = d
        self.rows += len(res)
        self.last_time_s = float(t[-1])
        self._prev = (float(t[-1]), int(ex[-1]), bool(valid[-1]))


def worst_events(events: Counter[int]) -> list[str]:
    """The most frequent notable event kinds as 'GAP x123'."""
    ranked = sorted(
        ((n, k) for k, n in events.items() if n and EventKind(k) not in _BENIGN),
        key=lambda nk: (-nk[0], nk[1]),
    )
    return [f"{EventKind(k).name} x{n}" for n, k in ranked[:WORST_EVENTS]]


def summary_row(stats: Stats, sink: SummarySink) -> dict[str, Any]:
    """The figures of one replayed log (the fields of :data:`LOGS_SCHEMA` that replay gives)."""
    samples = stats.samples
    span = sink.last_time_s - sink.first_time_s if sink.rows else 0.0
    return {
        "duration_s": span,
        "frames": stats.frames,
        "frames_by_id": [(f"0x{k:03X}", v) for k, v in sorted(stats.frames_by_id.items())],
        "crc_errors": stats.crc_errors,
        "wrong_dlc": stats.wrong_dlc,
        "unknown_id": stats.unknown_id,
        "link_errors": stats.link_errors,
        "parse_errors": stats.parse_errors,
        "gaps": sum(c.gaps for c in stats.channels),
        "duplicates": sum(c.duplicates for c in stats.channels),
        "samples": samples,
        "samples_lost": stats.samples_lost,
        "valid_pct": 100.0 * stats.valid / samples if samples else None,
        "degraded_pct": 100.0 * stats.degraded / samples if samples else None,
        "vote_failures_v1": stats.vote_failures[0],
        "vote_failures_v2": stats.vote_failures[1],
        "vote_failures_v3": stats.vote_failures[2],
        "invalid_spans": sink.invalid_spans,
        "excluded_ch1_s": sink.excluded_s[0],
        "excluded_ch2_s": sink.excluded_s[1],
        "excluded_ch3_s": sink.excluded_s[2],
        "max_ref_minus_est_permil": (
            None if math.isnan(sink.max_ref_minus_est) else sink.max_ref_minus_est
        ),
        "worst_events": worst_events(stats.events),
    }


def _f(name: str, kind: pa.DataType, unit: str, doc: str) -> pa.Field:
    return pa.field(name, kind, metadata={"unit": unit, "description": doc})


def _estimate_fields() -> list[pa.Field]:
    """The smoother's other estimates (fleet --smooth), one pair per model state by name."""
    from bench.replay.model_columns import per_log_fields

    out = []
    for column, sigma, unit, doc in per_log_fields():
        out.append(_f(column, pa.float64(), unit, f"median over the log of {doc}"))
        out.append(_f(sigma, pa.float64(), unit, "its median 1-sigma"))
    return out


_I = pa.int64()
LOGS_SCHEMA = pa.schema(
    [
        _f("log", pa.string(), "", "the log's id: file stem and content hash (results' `log`)"),
        _f("path", pa.string(), "", "the log file as given"),
        _f("content_hash", pa.string(), "", "sha256 of the file's bytes"),
        _f("format", pa.string(), "", "source format (candump, asc, blf, trc, csv, uart, mcap)"),
        _f("size_bytes", _I, "B", "file size"),
        _f("duration_s", pa.float64(), "s", "board time from the first to the last sample"),
        _f("frames", _I, "", "frames read"),
        _f("frames_by_id", pa.map_(pa.string(), _I), "", "frames per CAN ID"),
        _f("crc_errors", _I, "", "frames with a CRC mismatch"),
        _f("wrong_dlc", _I, "", "frames with the wrong length"),
        _f("unknown_id", _I, "", "frames with an ID the board does not send"),
        _f("link_errors", _I, "", "UART packets that failed to decode"),
        _f("parse_errors", _I, "", "log lines or records that could not be read"),
        _f("gaps", _I, "", "samples closed without a channel (all channels)"),
        _f("duplicates", _I, "", "duplicate frames (all channels)"),
        _f("samples", _I, "", "sampling instants fused"),
        _f("samples_lost", _I, "", "sampling instants missing from the counter sequence"),
        _f("valid_pct", pa.float64(), "%", "samples with a valid reference result"),
        _f("degraded_pct", pa.float64(), "%", "samples the estimator computed from two channels"),
        _f("vote_failures_v1", _I, "", "samples failing vote v1"),
        _f("vote_failures_v2", _I, "", "samples failing vote v2"),
        _f("vote_failures_v3", _I, "", "samples failing vote v3"),
        _f("invalid_spans", _I, "", "runs of consecutive invalid samples"),
        _f("excluded_ch1_s", pa.float64(), "s", "board time with ch1 excluded by the estimator"),
        _f("excluded_ch2_s", pa.float64(), "s", "board time with ch2 excluded by the estimator"),
        _f("excluded_ch3_s", pa.float64(), "s", "board time with ch3 excluded by the estimator"),
        _f("max_ref_minus_est_permil", pa.float64(), "permil",
           "largest |reference gradient - estimator's signed gradient|"),
        _f("worst_events", pa.list_(pa.string()), "", "most frequent event kinds"),
        _f("calibration", pa.string(), "", "the calibration used, as TOML"),
        _f("calibration_source", pa.string(), "", "where the calibration came from"),
        _f("result_rows", _I, "", "rows of this log in results/"),
        _f("smoothed", pa.bool_(), "", "results/ has the smoother's columns (fleet --smooth)"),
        _f("wheel_diameter_error", pa.float64(), "1",
           "the odometer's wheel-scale error the smoother found (SPEED_REF = (1 + e) v)"),
        _f("wheel_diameter_error_sigma", pa.float64(), "1", "its 1-sigma"),
        *_estimate_fields(),
        _f("wall_s", pa.float64(), "s", "time the replay took"),
        _f("bench_version", pa.string(), "", "bench version that replayed the log"),
        _f("error", pa.string(), "", "why the log could not be replayed; null when it was"),
    ]
)  # fmt: skip
"""``logs.parquet``: one row per log (a log that could not be read: its error, the rest null)."""


def logs_table(rows: list[dict[str, Any]]) -> pa.Table:
    """Rows (dicts with any subset of LOGS_SCHEMA's fields) as one table of LOGS_SCHEMA."""
    return pa.Table.from_pylist(
        [{name: row.get(name) for name in LOGS_SCHEMA.names} for row in rows], schema=LOGS_SCHEMA
    )
