"""Replay throughput from candump, BLF and MCAP, next to the bare library readers; MCAP write.

All three logs hold the same frames: ``n`` frames of the 1 kHz virtual board.

* The bench figure is the whole ``bench replay`` path without an output file:
  ``replay(open_log(path), Config())`` -- read, decode, assemble, fuse, estimator, events,
  statistics. With the results CSV and with the Parquet file (pyarrow, in a writer thread
  of their own) it is reported separately (``replay candump + CSV``, ``+ Parquet``), against
  the same LogReader anchor: issue 17's target is the whole replay + CSV in <= 1/3 of the
  LogReader's time, i.e. >= 3x its frame rate.
* The anchor for .log and .blf is python-can's bare iteration, nothing else:
  ``for msg in can.LogReader(path): pass``.
* python-can cannot read MCAP; the MCAP anchor is the ``mcap`` package's own reader iterating
  the same file's frame messages (``make_reader(f).iter_messages(topics=[...])``).
* MCAP write: a :class:`bench.mcaplog.sink.McapSink` (what a live run logs: frames,
  samples, results, status, events) fed the pipeline steps of the whole log, from the
  first ``write`` to the end of ``close()`` (summary and footer written). The file it
  writes is the one the MCAP replay then reads, i.e. a recorded run.
"""

from __future__ import annotations

import tempfile
import time
from functools import partial
from pathlib import Path
from typing import Any

from benchmarks.common import Figure, frames_for, timed, timed_pair, warm_file

CANDUMP_RATIO_TARGET = 3.0
CSV_RATIO_TARGET = 3.0  # replay + CSV in <= 1/3 of python-can's LogReader time (issue 17)
MCAP_REPLAY_TARGET = 2e6


def logreader_iterate(path: Path) -> int:
    """The anchor: python-can's bare LogReader iteration."""
    import can

    n = 0
    for _msg in can.LogReader(path):
        n += 1
    return n


def mcap_iterate(path: Path, topic: str) -> int:
    """The MCAP anchor: the mcap package's reader over the frame messages."""
    from mcap.reader import make_reader

    n = 0
    with open(path, "rb") as f:
        for _ in make_reader(f).iter_messages(topics=[topic]):
            n += 1
    return n


def bench_replay(path: Path, csv: Path | None = None, parquet: Path | None = None) -> Any:
    """The bench's replay path, as `bench replay` runs it (collect=False, no summary), with
    the results CSV and/or Parquet file written as `--csv` / `--parquet` write them."""
    from bench.config import Config
    from bench.replay.run import replay
    from bench.sinks.tables import csv_sink, parquet_sink
    from devices.formats import open_log

    source = open_log(path)
    sinks = []
    if csv is not None:
        sinks.append(csv_sink(csv))
    if parquet is not None:
        sinks.append(parquet_sink(parquet))
    try:
        return replay(source, Config(), sinks, collect=False)
    finally:
        for s in sinks:
            s.close()
        source.close()


def read_only(path: Path) -> int:
    """The bench's reader alone: open_log(path).batches() (what replay feeds the pipeline)."""
    from devices.formats import open_log

    source = open_log(path)
    try:
        return sum(len(b.frames) for b in source.batches(65536))
    finally:
        source.close()


def pipeline_only(frames: Any, batch: int = 65536) -> int:
    """The pipeline alone on frames already in memory, in replay's batch size."""
    from bench.config import Config
    from bench.pipeline.steps import Pipeline
    from devices.base import SourceBatch

    p = Pipeline(Config())
    for i in range(0, len(frames), batch):
        p.process(SourceBatch(frames[i : i + batch]))
    p.finish()
    return p.seq


def pipeline_steps(frames: Any, batch: int = 65536) -> list[Any]:
    from bench.config import Config
    from bench.pipeline.steps import Pipeline
    from devices.base import SourceBatch

    p = Pipeline(Config())
    steps = [p.process(SourceBatch(frames[i : i + batch])) for i in range(0, len(frames), batch)]
    steps.append(p.finish())
    return steps


def write_mcap(path: Path, steps: list[Any]) -> Any:
    from bench.config import Config
    from bench.mcaplog.sink import McapSink

    sink = McapSink(path, Config(), {"source": "benchmark", "mode": "benchmark"})
    for step in steps:
        sink.write(step)
    sink.close()
    return sink


def _replay_vs(
    key: str,
    label: str,
    path: Path,
    anchor_fn: Any,
    anchor_label: str,
    repeat: int,
    n: int,
    anchor_repeat: int | None = None,
    **target: Any,
) -> Figure:
    """Bench replay of ``path`` timed alternately with its anchor (best of ``repeat`` each;
    a slow anchor is timed once, after which the bench gets its remaining runs)."""
    warm_file(path)
    a_repeat = repeat if anchor_repeat is None else anchor_repeat
    (a_dt, a_n), (dt, out) = timed_pair(anchor_fn, lambda: bench_replay(path), a_repeat)
    if repeat > a_repeat:
        dt2, out = timed(lambda: bench_replay(path), repeat - a_repeat)
        dt = min(dt, dt2)
    anchor = a_n / a_dt
    seq = out.pipeline.seq
    return Figure(
        key,
        label,
        seq / dt,
        "frames/s",
        anchor=anchor,
        anchor_label=anchor_label,
        detail=f"{seq} frames, {out.pipeline.stats.samples} samples in {dt:.2f} s (best of "
        f"{repeat}; anchor {a_dt:.2f} s, best of {a_repeat}); {path.stat().st_size / 1e6:.0f} MB",
        extra={
            "frames": seq,
            "seconds": dt,
            "expected_frames": n,
            "anchor_frames": a_n,
            "anchor_seconds": a_dt,
        },
        **target,
    )


def measure(
    n_frames: int = 1_000_000,
    repeat: int = 3,
    workdir: str | None = None,
    out: list[Figure] | None = None,
) -> list[Figure]:
    """Every replay figure; each is appended to ``out`` (if given) as soon as it is taken."""
    from bench.mcaplog.schemas import FRAME_TOPIC
    from devices.writers import write_candump, write_with_can_logger

    figures: list[Figure] = out if out is not None else []
    with tempfile.TemporaryDirectory(prefix="bench-replay-", dir=workdir) as tmp:
        d = Path(tmp)
        t0 = time.perf_counter()
        frames = frames_for(n_frames)
        log, blf, mcap = d / "board.log", d / "board.blf", d / "board.mcap"
        write_candump(log, frames)
        write_with_can_logger(blf, frames)
        gen_s = time.perf_counter() - t0

        # -- candump ------------------------------------------------------------------------
        fig = _replay_vs(
            "replay_candump",
            "replay candump .log",
            log,
            lambda: logreader_iterate(log),
            "python-can LogReader",
            repeat,
            n_frames,
            target=CANDUMP_RATIO_TARGET,
            on="ratio",
        )
        fig.extra["generation_s"] = gen_s
        figures.append(fig)

        for key, label, kw in (
            ("replay_candump_csv", "replay candump .log + CSV", {"csv": d / "out.csv"}),
            ("replay_candump_parquet", "replay candump .log + Parquet", {"parquet": d / "o.pq"}),
        ):
            out_file = next(iter(kw.values()))
            dt, res = timed(partial(bench_replay, log, **kw), repeat)
            anchor_s = fig.extra["anchor_seconds"]
            figures.append(
                Figure(
                    key,
                    label,
                    res.pipeline.seq / dt,
                    "frames/s",
                    anchor=fig.anchor,
                    anchor_label="python-can LogReader",
                    detail=f"the whole replay writing the per-sample results "
                    f"({out_file.stat().st_size / 1e6:.0f} MB, {res.pipeline.stats.samples} rows) "
                    f"in {dt:.2f} s, best of {repeat}; LogReader {anchor_s:.2f} s",
                    target=CSV_RATIO_TARGET,
                    on="ratio",
                    extra={"seconds": dt, "bytes": out_file.stat().st_size},
                )
            )
            out_file.unlink()

        # -- BLF ----------------------------------------------------------------------------
        figures.append(
            _replay_vs(
                "replay_blf",
                "replay BLF .blf",
                blf,
                lambda: logreader_iterate(blf),
                "python-can LogReader",
                repeat,
                n_frames,
                anchor_repeat=min(repeat, 2),
            )
        )

        # -- MCAP write, then MCAP replay of that recorded run --------------------------------
        steps = pipeline_steps(frames)
        n_results = sum(len(s.results) for s in steps)
        t0 = time.perf_counter()
        sink = write_mcap(mcap, steps)
        dt = time.perf_counter() - t0
        del steps
        figures.append(
            Figure(
                "mcap_write",
                "MCAP write (McapSink, full run log)",
                len(frames) / dt,
                "frames/s",
                detail=f"{len(frames)} frames + {n_results} results, samples, events; "
                f"{mcap.stat().st_size / 1e6:.0f} MB zstd; write+close {dt:.2f} s; "
                f"logged {sink.frames_logged}",
                error=sink.error or "",
                extra={"frames_logged": sink.frames_logged, "dropped": sink.dropped},
            )
        )
        figures.append(
            _replay_vs(
                "replay_mcap",
                "replay MCAP (recorded run)",
                mcap,
                lambda: mcap_iterate(mcap, FRAME_TOPIC),
                "mcap package reader",
                repeat,
                n_frames,
                anchor_repeat=1,  # ~40 s per run for 1 M frames; it sets no target
                target=MCAP_REPLAY_TARGET,
            )
        )

        # -- where the replay time goes: each reader alone, the pipeline alone ----------------
        for key, label, path in (
            ("read_candump", "  candump reader alone", log),
            ("read_mcap", "  MCAP reader alone", mcap),
        ):
            dt, n = timed(partial(read_only, path), repeat)
            figures.append(
                Figure(key, label, n / dt, "frames/s", detail=f"open_log().batches(): {n} frames")
            )
        dt, n = timed(lambda: pipeline_only(frames), repeat)
        figures.append(
            Figure(
                "pipeline_only",
                "  pipeline alone (frames in memory)",
                n / dt,
                "frames/s",
                detail="decode, assemble, fuse, estimator, events, stats; 65536-frame steps",
            )
        )
    return figures
