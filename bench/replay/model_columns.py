"""The explicit model's estimates as result columns of `bench replay --smooth` (issue 26).

Every state of the model (bench.fusion.model.state.NAMES) that is an estimate of the
board, the odometer or the car rather than of the motion becomes two columns, its smoothed
value and its 1-sigma, per sample: the wheel-diameter error, each channel's bias, the
odometer's latency, the body's static pitch, and any state the model gains later (named
``model_<name>_smoothed`` until it has an entry in :data:`KNOWN`). Per sample, not once per
run: in the model each of them walks (the biases in time, a drifting channel being a large
bias; the pitch at stands; the wheel scale per metre), so the smoothed track is the
estimate, and a Parquet column that stays constant costs a few bytes.
"""

from __future__ import annotations

import dataclasses
import json
from typing import TYPE_CHECKING

import numpy as np

from bench.fusion.model import state
from bench.mcaplog.schemas import RESULT_TOPIC, Column, columns_for
from bench.records.columns import RESULT_FIELDS, Layout
from bench.records.results import RESULT_DTYPE, SMOOTHED_DTYPE

if TYPE_CHECKING:
    from bench.fusion.model.log import Smoothed
    from bench.mcaplog.reader import McapLog

MOTION = frozenset({"v", "a", "s", "k", "accel_pitch", "accel_pitch_rate"})
"""States of the motion and the track, not columns here: S is the gradient (its own column),
speed and acceleration are the odometer's and a_ref's business, and the body's pitch under
acceleration follows the acceleration (its compliance is the car's estimate)."""

KNOWN: dict[str, tuple[str, str, str]] = {
    "e": (
        "wheel_diameter_error_smoothed",
        "1",
        "the odometer's wheel-scale error E the model found (SPEED_REF = (1 + E) v: a wheel "
        "worn below its configured diameter reads high, E > 0)",
    ),
    "b1": ("bias1_smoothed_mps2", "m/s^2", "channel 1's bias left after calibration"),
    "b2": ("bias2_smoothed_mps2", "m/s^2", "channel 2's bias left after calibration"),
    "b3": ("bias3_smoothed_mps2", "m/s^2", "channel 3's bias left after calibration"),
    "latency": (
        "odometer_latency_smoothed_s",
        "s",
        "the odometer's latency beyond its clock mapping: SPEED_REF reads v(t - latency)",
    ),
    "pitch": (
        "body_pitch_smoothed_rad",
        "rad",
        "the car body's static pitch on its suspension (the load), nose up",
    ),
    "compliance": (
        "pitch_compliance_smoothed_rad_per_mps2",
        "rad/(m/s^2)",
        "the car body's pitch per m/s^2 of acceleration once settled, nose up accelerating",
    ),
}
"""State name -> (value column, unit, meaning). The sigma column is the value column with
``_sigma`` before the unit suffix."""

_SUFFIX = {"m/s^2": "_mps2", "s": "_s", "rad": "_rad", "rad/(m/s^2)": "_rad_per_mps2"}


def estimate_names() -> tuple[str, ...]:
    """The model's states that become columns, in state order."""
    return tuple(n for n in state.NAMES if n not in MOTION)


def _entry(name: str) -> tuple[str, str, str]:
    return KNOWN.get(
        name,
        (f"model_{name}_smoothed", "", f"the explicit model's state {name!r} "
         "(bench/fusion/model/state.py gives its unit)"),
    )  # fmt: skip


def _sigma_column(column: str, unit: str) -> str:
    suffix = _SUFFIX.get(unit, "")
    stem = column[: -len(suffix)] if suffix and column.endswith(suffix) else column
    return f"{stem}_sigma{suffix}"


def fields_and_dtype() -> tuple[dict[str, tuple[tuple[str, ...], str, str]], np.dtype]:
    """The columns table (RESULT_FIELDS and one value and sigma entry per estimate) and
    the rows' dtype (SMOOTHED_DTYPE and fields ``model_<name>``, ``model_<name>_sigma``)."""
    table = dict(RESULT_FIELDS)
    extra: list[tuple[str, str]] = []
    for name in estimate_names():
        column, unit, doc = _entry(name)
        table[f"model_{name}"] = ((column,), unit, f"{doc}; smoothed over the whole log")
        table[f"model_{name}_sigma"] = ((_sigma_column(column, unit),), unit, "its 1-sigma")
        extra += [(f"model_{name}", "<f8"), (f"model_{name}_sigma", "<f8")]
    return table, np.dtype([*SMOOTHED_DTYPE.descr, *extra])


MODEL_FIELDS, MODEL_DTYPE = fields_and_dtype()
LAYOUT = Layout(MODEL_DTYPE, MODEL_FIELDS, utc_after="time_s")
"""The results of `bench replay --smooth`: the filtered columns, the smoothed gradient and
its sigma, then each estimate and its sigma."""


def mcap_columns() -> list[Column]:
    """The MCAP results' JSON properties of MODEL_DTYPE rows (`bench replay --smooth
    --mcap`): RESULT_DTYPE's, then each smoother field by its dtype name (``model_e``, ...),
    described with its CSV column and unit."""
    out = []
    for col in columns_for(MODEL_DTYPE):
        if col.field not in (RESULT_DTYPE.names or ()):
            (column,), unit, doc = MODEL_FIELDS[col.field]
            unit_text = f", {unit}" if unit else ""
            col = dataclasses.replace(col, description=f"{column}{unit_text}: {doc}")
        out.append(col)
    return out


_SHOWN = {  # state name -> (label, unit shown, factor from SI)
    "b1": ("ch1 bias", "mm/s^2", 1e3),
    "b2": ("ch2 bias", "mm/s^2", 1e3),
    "b3": ("ch3 bias", "mm/s^2", 1e3),
    "latency": ("odometer latency", "ms", 1e3),
    "pitch": ("body pitch", "deg", 180.0 / np.pi),
    "compliance": ("pitch compliance", "deg per m/s^2", 180.0 / np.pi),
}


def describe_estimates(smoothed: Smoothed) -> str:
    """One line of the run's estimates but E (which Smoothed.describe gives): each one's
    median over the run and median 1-sigma, "moving" where it spans more than its 2 sigma
    (a drifting channel, a load step)."""
    got = block_summary(smoothed)
    parts = []
    for name in estimate_names():
        (column,), _, _ = MODEL_FIELDS[f"model_{name}"]
        if name == "e" or column not in got:
            continue
        label, unit, factor = _SHOWN.get(name, (name, "", 1.0))
        one = {k: float(v) * factor for k, v in got[column].items() if k != "unit"}
        text = f"{label} {one['median']:+.3g} {unit} (1-sigma {one['sigma']:.2g})"
        text = text.replace("  ", " ")
        if one["max"] - one["min"] > 2.0 * one["sigma"]:
            text += f" moving {one['min']:+.3g}..{one['max']:+.3g}"
        parts.append(text)
    return "smoother: " + ", ".join(parts) if parts else ""


def recorded_smoothed(lg: McapLog) -> np.ndarray | None:
    """A `bench replay --smooth --mcap` file's results as MODEL_DTYPE rows (None for a file
    whose results schema has no smoothed gradient: a live run's). A field of a state the
    file's model did not have is NaN, not the decoder's 0."""
    cid = lg.channel_id(RESULT_TOPIC)
    schema = lg.schemas.get(lg.channels[cid].schema_id) if cid is not None else None
    if schema is None:
        return None
    try:
        props = json.loads(schema.data).get("properties", {})
    except (ValueError, AttributeError):
        return None
    if "gradient_smoothed" not in props:
        return None
    rows = lg.table(RESULT_TOPIC, mcap_columns(), MODEL_DTYPE)
    for name in MODEL_DTYPE.names or ():
        if name not in (RESULT_DTYPE.names or ()) and name not in props:
            rows[name] = np.nan
    return rows


def _summary(x: np.ndarray, sig: np.ndarray, unit: str) -> dict[str, float | str] | None:
    ok = np.isfinite(x)
    if not ok.any():
        return None
    return {
        "median": float(np.median(x[ok])),
        "sigma": float(np.median(sig[ok])),
        "min": float(x[ok].min()),
        "max": float(x[ok].max()),
        "unit": unit,
    }


def estimate_summary(rows: np.ndarray) -> dict[str, dict[str, float | str]]:
    """Per estimate column of MODEL_DTYPE ``rows``: its median over the run, its median
    1-sigma, its least and largest value and its unit (what a run's record keeps)."""
    out: dict[str, dict[str, float | str]] = {}
    for name in estimate_names():
        (column,), unit, _ = MODEL_FIELDS[f"model_{name}"]
        got = _summary(rows[f"model_{name}"], rows[f"model_{name}_sigma"], unit)
        if got is not None:
            out[column] = got
    return out


def block_summary(smoothed: Smoothed) -> dict[str, dict[str, float | str]]:
    """:func:`estimate_summary` from the smoother's own per-block states (the same medians
    up to the blocks' weights: a block is a run of samples)."""
    out: dict[str, dict[str, float | str]] = {}
    for name in estimate_names():
        i = state.NAMES.index(name)
        (column,), unit, _ = MODEL_FIELDS[f"model_{name}"]
        if len(smoothed.states):
            got = _summary(smoothed.states[:, i], smoothed.states_sigma[:, i], unit)
            if got is not None:
                out[column] = got
    return out


def per_log_fields() -> list[tuple[str, str, str, str]]:
    """(value column, sigma column, unit, meaning) of each estimate but E (which has its
    own fields): what `bench fleet --smooth` puts in logs.parquet, medians over the log."""
    out = []
    for name in estimate_names():
        if name == "e":
            continue
        (column,), unit, doc = MODEL_FIELDS[f"model_{name}"]
        (sigma,), _, _ = MODEL_FIELDS[f"model_{name}_sigma"]
        out.append((column, sigma, unit, doc))
    return out


def per_log_row(smoothed: Smoothed) -> dict[str, float]:
    """The :func:`per_log_fields` of one smoothed log: each median and median 1-sigma."""
    got = block_summary(smoothed)
    row: dict[str, float] = {}
    for column, sigma, _, _ in per_log_fields():
        if column in got:
            row[column] = float(got[column]["median"])
            row[sigma] = float(got[column]["sigma"])
    return row
