"""Checks on the smoothed gradient (``estimator = "smoothed"``, issue 26): the run's log
smoothed after the run, its columns joined to the run's results by sample counter.

The explicit model's RTS smoother needs the whole run, so it runs once the run is over,
over the frames the run recorded in DIR/run.mcap (bench.replay.smooth.smoothed_rows),
whatever the mode: emulated, realtime or live. Only a plan with such a check pays for the
extra reading. The run's own results stay as they were (they are the live path's); a
result whose sample the log did not hold (a frame the recording lost) gets no smoothed
gradient, which the checks count as withheld, never as right.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from bench.acceptance.model import RunData
from bench.config import Config
from bench.replay.model_columns import MODEL_DTYPE, estimate_summary


def smoothed_run(
    run: RunData, log_path: Path, config: Config, info: dict[str, Any] | None = None
) -> RunData:
    """``run`` with MODEL_DTYPE results: the smoother's columns from ``log_path``; ``info``
    (the record's run section) gets the run's estimates under ``smoother``."""
    from bench.replay.smooth import smoothed_rows
    from devices.formats import open_log

    source = open_log(str(log_path))
    try:
        rows = smoothed_rows(source, config)
    finally:
        source.close()
    if info is not None:
        info["smoother"] = estimate_summary(rows)
    return dataclasses.replace(run, results=join_by_counter(run.results, rows), _k=None)


def join_by_counter(results: np.ndarray, smoothed: np.ndarray) -> np.ndarray:
    """``results`` as MODEL_DTYPE rows, the smoothed columns of the row of ``smoothed`` with
    the same sample counter ``n`` (NaN where there is none)."""
    out = np.empty(len(results), dtype=MODEL_DTYPE)
    names = results.dtype.names or ()
    for name in names:
        out[name] = results[name]
    new = [n for n in MODEL_DTYPE.names or () if n not in names]
    for name in new:
        out[name] = np.nan
    if not len(smoothed) or not len(results):
        return out
    order = np.argsort(smoothed["n"], kind="stable")
    sn = smoothed["n"][order]
    pos = np.clip(np.searchsorted(sn, results["n"]), 0, len(sn) - 1)
    hit = sn[pos] == results["n"]
    src = order[pos[hit]]
    for name in new:
        out[name][hit] = smoothed[name][src]
    return out
