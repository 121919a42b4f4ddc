"""`bench replay --smooth`: the explicit model's RTS smoother beside the filtered columns.

A fixed-interval smoother needs the whole log before its first value, and a replay must
not hold all its results at once, so the log is read twice: the first pass keeps only
what the estimator's filter is given (bench.fusion.model.log.ModelLog) and smooths it;
the second is the ordinary replay, each step's results joined to the smoothed gradient of
the same samples on their way to the CSV/Parquet files. The filtered columns are those of
a replay without --smooth, to the bit (the pipeline is the same and the smoother only
reads).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable

import numpy as np

from bench.config import Config
from bench.errors import BenchError
from bench.fusion.estimator import Estimator
from bench.fusion.model import state
from bench.fusion.model.log import ModelLog, Smoothed
from bench.pipeline.steps import Pipeline, StepOutput
from bench.records.results import RESULT_DTYPE
from bench.replay.model_columns import MODEL_DTYPE, estimate_names
from bench.replay.prefetch import prefetch
from bench.replay.run import run_steps
from bench.sinks.base import Sink
from bench.sinks.tables import TableSink
from devices.base import FileSource


def smoothing_pass(source: FileSource, config: Config, batch_frames: int = 65536) -> Smoothed:
    """Read ``source`` once through a fresh pipeline and smooth what its filter was given."""
    pipeline = Pipeline(config)
    assert isinstance(pipeline.estimator, Estimator)
    log = ModelLog()
    pipeline.estimator.log = log
    for _ in run_steps(pipeline, prefetch(source.batches(batch_frames))):
        pass
    return log.smooth(config)


def smoothed_rows(source: FileSource, config: Config, batch_frames: int = 65536) -> np.ndarray:
    """The whole log's results with the smoother's columns (MODEL_DTYPE), from one reading:
    for a short run held in memory at once (an acceptance run's checks), not a replay."""
    pipeline = Pipeline(config)
    assert isinstance(pipeline.estimator, Estimator)
    log = ModelLog()
    pipeline.estimator.log = log
    parts = [step.results for step in run_steps(pipeline, source.batches(batch_frames))]
    results = np.concatenate(parts) if parts else np.zeros(0, dtype=RESULT_DTYPE)
    return with_smoothed(results, log.smooth(config), 0)


def with_smoothed(results: np.ndarray, smoothed: Smoothed, start: int) -> np.ndarray:
    """``results`` (RESULT_DTYPE) as MODEL_DTYPE rows, the smoothed gradient and the model's
    estimates (bench.replay.model_columns) of samples ``start`` .. ``start + len(results)``
    of the log joined."""
    out = np.empty(len(results), dtype=MODEL_DTYPE)
    for name in results.dtype.names or ():
        out[name] = results[name]
    stop = start + len(results)
    if stop > len(smoothed.smoothed):
        raise BenchError(
            "the log gave more samples on its second reading than on its first: "
            "it changed while replayed"
        )
    out["gradient_smoothed"] = smoothed.smoothed[start:stop]
    out["gradient_smoothed_sigma"] = smoothed.smoothed_sigma[start:stop]
    blocks = np.arange(start, stop) // smoothed.block
    for name in estimate_names():
        i = state.NAMES.index(name)
        out[f"model_{name}"] = smoothed.states[blocks, i]
        out[f"model_{name}_sigma"] = smoothed.states_sigma[blocks, i]
    return out


class SmoothedSinks(Sink):
    """A sink that writes each step's results, with the smoothed columns, to table sinks
    made with the :data:`~bench.replay.model_columns.LAYOUT` layout."""

    def __init__(
        self, sinks: Iterable[TableSink], smoothed: Smoothed, step_sinks: Iterable[Sink] = ()
    ) -> None:
        """``step_sinks`` (the MCAP log) get each whole step, its results joined."""
        self.sinks = list(sinks)
        self.step_sinks = list(step_sinks)
        self.smoothed = smoothed
        self.rows = 0  # results joined so far

    def write(self, step: StepOutput) -> None:
        rows = with_smoothed(step.results, self.smoothed, self.rows)
        self.rows += len(rows)
        for sink in self.step_sinks:
            sink.write(dataclasses.replace(step, results=rows))
        if not len(rows):
            return
        for sink in self.sinks:
            sink.put(rows)

    def check_complete(self) -> None:
        """Both readings of the log gave the same number of samples."""
        if self.rows != len(self.smoothed.smoothed):
            raise BenchError(
                f"the log gave {self.rows} samples on its second reading and "
                f"{len(self.smoothed.smoothed)} on its first: it changed while replayed"
            )
