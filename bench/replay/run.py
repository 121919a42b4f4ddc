"""Replay a recorded log through the same pipeline a live run uses."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from bench.config import Config
from bench.errors import BenchError
from bench.pipeline.steps import Pipeline, StepOutput
from bench.records.results import RESULT_DTYPE
from bench.replay.prefetch import ReadAhead
from bench.sinks.base import Sink
from devices.base import FileSource, SourceBatch
from devices.tomlcheck import printable

READ_AHEAD = 4
"""Batches read ahead of the pipeline (65 536 frames each, 1.5 MB): while the pipeline is
built, the reading gets that far."""


@dataclass
class ReplayOutcome:
    pipeline: Pipeline
    results: np.ndarray  # every result, when collected (else empty)
    notices: list[str] = field(default_factory=list)


def run_steps(pipeline: Pipeline, batches: Iterable[SourceBatch]) -> Iterable[StepOutput]:
    """Every pipeline step for a stream of batches, ending with the final flush."""
    for batch in batches:
        yield pipeline.process(batch)
    yield pipeline.finish()


def replay(
    source: FileSource,
    config: Config,
    sinks: Iterable[Sink] = (),
    *,
    collect: bool = True,
    batch_frames: int = 65536,
    on_progress: Callable[[int], None] | None = None,
) -> ReplayOutcome:
    """Run a log through a fresh Pipeline, feeding each step to the sinks.

    The source is read a few batches ahead in a thread of its own (bench.replay.prefetch),
    which starts before the pipeline is built: the estimator's kernels load meanwhile."""
    ahead = ReadAhead(source.batches(batch_frames), depth=READ_AHEAD)
    sinks = list(sinks)
    parts: list[np.ndarray] = []
    notices: list[str] = []
    try:
        pipeline = Pipeline(config)
        for step in run_steps(pipeline, ahead):
            if step.batch is not None:
                notices += [f"{n.kind}: {n.detail}" for n in step.batch.notices]
            for sink in sinks:
                sink.write(step)
            if collect and len(step.results):
                parts.append(step.results)
            if on_progress is not None:
                on_progress(source.position())
    finally:
        ahead.close()
    results = np.concatenate(parts) if parts else np.zeros(0, dtype=RESULT_DTYPE)
    return ReplayOutcome(pipeline, results, notices)


def no_frames(path: object, notices: list[str]) -> BenchError:
    """The one-line error for a log that yielded no frame at all (random bytes with a log's
    extension, an MCAP cut before its first chunk): an empty replay is no replay."""
    why = ""
    if notices:
        first = notices[0].split(": ", 1)[-1].removeprefix(f"{path}: ")
        first = printable(first)
        if len(first) > 160:
            first = first[:157] + "..."
        more = f"{len(notices)} problems, the first: " if len(notices) > 1 else ""
        why = f" ({more}{first})"
    return BenchError(f"{path}: no frame in this log{why}")
