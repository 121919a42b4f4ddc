"""Replay a recorded log through the same pipeline a live run uses."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np

from bench.config import Config
from bench.errors import BenchError
from bench.pipeline.steps import Pipeline, Referenced, StepOutput, new_estimator
from bench.records.results import RESULT_DTYPE
from bench.replay.prefetch import ReadAhead
from bench.sinks.base import Sink
from devices.base import FileSource, SourceBatch
from devices.tomlcheck import printable

READ_AHEAD = 4
"""Batches read ahead of the pipeline (65 536 frames each, 1.5 MB): while the pipeline is
built, the reading gets that far."""
FIRST_STEP_FRAMES = 4096
"""The frames of a replay's first step, cut from the log's first batch (a candump log's
first megabyte holds about 25 000): the first frames are decoded, assembled and fused in a
few milliseconds instead of after the whole batch, whose first stage, beside the estimator's
kernels loading under the GIL, took about 0.1 s. The steps' rows do not depend on where a
batch is cut (bench.pipeline.steps)."""
REFERENCED_AHEAD = 8
"""Steps the first stage (decode, assembly, the reference method) runs ahead of the
estimator's (about 9 MB each): what it gets done while the estimator's kernels load."""


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


def first_cut(batches: Iterable[SourceBatch], frames: int) -> Iterator[SourceBatch]:
    """``batches`` with the first cut in two after ``frames`` frames (when it holds more, and
    no link errors or notices: those stay with their batch, uncut)."""
    it = iter(batches)
    for batch in it:
        if len(batch.frames) > frames and not batch.link_errors and not batch.notices:
            yield SourceBatch(batch.frames[:frames])
            yield SourceBatch(batch.frames[frames:])
        else:
            yield batch
        break
    yield from it


def referenced(pipeline: Pipeline, batches: Iterable[SourceBatch]) -> Iterator[Referenced]:
    """The first stage of every step (bench.pipeline.steps), ending with the final flush's."""
    for batch in batches:
        yield pipeline.reference(batch)
    yield pipeline.reference_finish()


def replay(
    source: FileSource,
    config: Config,
    sinks: Iterable[Sink] = (),
    *,
    collect: bool = True,
    batch_frames: int = 65536,
    on_progress: Callable[[int], None] | None = None,
    before_estimator: Callable[[], object] | None = None,
) -> ReplayOutcome:
    """Run a log through a fresh Pipeline, feeding each step to the sinks.

    Three threads, each stage's work in order: the source is read a few batches ahead
    (bench.replay.prefetch); a second thread runs the pipeline's first stage (decode,
    assembly, the reference method) on them; this one builds the estimator (its kernels
    load from numba's cache: about 0.3 s of a replay's start, under the GIL) and completes
    each step, then feeds it to the sinks. ``before_estimator`` runs here first (a headless
    command's word that a first start compiles)."""
    ahead = ReadAhead(first_cut(source.batches(batch_frames), FIRST_STEP_FRAMES), READ_AHEAD)
    sinks = list(sinks)
    parts: list[np.ndarray] = []
    notices: list[str] = []
    pipeline = Pipeline(config, later=True)
    first = ReadAhead(referenced(pipeline, ahead), depth=REFERENCED_AHEAD)
    try:
        if before_estimator is not None:
            before_estimator()
        pipeline.estimator = new_estimator(config)  # built now, while the first stage runs
        for half in first:
            step = pipeline.estimate(half)
            if step.batch is not None:
                notices += [f"{n.kind}: {n.detail}" for n in step.batch.notices]
            for sink in sinks:
                sink.write(step)
            if collect and len(step.results):
                parts.append(step.results)
            if on_progress is not None:
                on_progress(source.position())
    finally:
        first.close()
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
