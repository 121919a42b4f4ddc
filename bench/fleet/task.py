"""One fleet task: hash a log, replay it, write its results partition, return its summary row.

Runs on a Dask worker (any machine that sees the output folder at the same path). Never
raises for a bad log: a log that cannot be read is a row with its error.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import time
from pathlib import Path
from typing import Any

from devices.formats import log_formats
from devices.paths import regular_file_problem

RESULTS_DIR = "results"
PART_FILE = "part-0.parquet"


def content_hash(path: str | Path, block: int = 1 << 20) -> str:
    """sha256 of the file's bytes (hashlib releases the GIL on large blocks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(block):
            h.update(chunk)
    return h.hexdigest()


def log_id(path: str | Path, digest: str) -> str:
    """The log's name in results/ (``log=<id>``): its stem, made path- and SQL-friendly,
    and the start of its content hash (two files of one name stay apart)."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(path).stem).strip("._") or "log"
    return f"{stem[:60]}-{digest[:12]}"


def partition(out_dir: str | Path, lid: str) -> Path:
    return Path(out_dir) / RESULTS_DIR / f"log={lid}"


def replay_one(
    path: str,
    out_dir: str,
    config_toml: str | None,
    done: frozenset[str] = frozenset(),
    smooth: bool = False,
) -> dict[str, Any]:
    """Replay ``path`` into ``out_dir/results/log=<id>/`` and return its logs.parquet row.
    ``done``: content hashes already replayed (the row then only says ``skipped``);
    ``smooth``: the results get the smoother's columns (bench.replay.smooth)."""
    from bench import __version__

    start = time.perf_counter()
    suffix = Path(path).suffix.lower()
    row: dict[str, Any] = {
        "path": str(path),
        "format": log_formats().get(suffix, suffix.lstrip(".")),
        "bench_version": __version__,
    }
    try:
        if why := regular_file_problem(path):  # a FIFO or a device would be hashed forever
            raise OSError(why)
        row["size_bytes"] = os.path.getsize(path)
        digest = content_hash(path)
    except OSError as exc:
        row["error"] = f"cannot read: {exc.strerror or exc}"
        row["log"] = log_id(path, "0" * 64)
        return row
    row["content_hash"] = digest
    row["log"] = lid = log_id(path, digest)
    if digest in done:
        row["skipped"] = True
        return row
    part = partition(out_dir, lid)
    try:
        row.update(_replay_into(path, part / PART_FILE, config_toml, smooth))
    except Exception as exc:  # a log that cannot be read is a row, never the end of the run
        from bench.errors import BenchError

        row["error"] = str(exc) if isinstance(exc, BenchError) else f"{type(exc).__name__}: {exc}"
        with contextlib.suppress(OSError):
            (part / PART_FILE).unlink()
        with contextlib.suppress(OSError):
            part.rmdir()
    row["wall_s"] = time.perf_counter() - start
    return row


_CONFIG_TOML: dict[str, Any] = {}
"""Configs parsed on this worker, by their TOML text."""


def _config_for(path: str, config_toml: str | None) -> Any:
    """The calibration: the one given (as TOML), else what `bench replay` would use (an MCAP
    log's recorded one, else nominal: bench.config_choice.replay_config) but for the bench's
    default sheet: a fleet's logs come from many boards, and a worker's folder is not the
    client's."""
    import tomllib

    from bench.config import config_from_dict
    from bench.config_choice import replay_config

    if config_toml is None:
        return replay_config(None, path, use_defaults=False)
    if config_toml not in _CONFIG_TOML:
        data = tomllib.loads(config_toml)
        name = data.pop("_path", "--config")  # the client's file name, for the record
        _CONFIG_TOML[config_toml] = config_from_dict(data, source=name, path=name)
    return _CONFIG_TOML[config_toml]


def _replay_into(
    path: str, target: Path, config_toml: str | None, smooth: bool = False
) -> dict[str, Any]:
    from bench.fleet.summary import SummarySink, summary_row
    from bench.records.columns import RESULTS
    from bench.replay.model_columns import LAYOUT as SMOOTHED
    from bench.replay.model_columns import per_log_row
    from bench.replay.run import no_frames, replay
    from bench.replay.smooth import SmoothedSinks, smoothing_pass
    from bench.sinks.tables import abort_all, parquet_sink, results_metadata
    from devices.formats import open_log

    config = _config_for(path, config_toml)
    smoothed = None
    if smooth:  # the smoother's own reading of the log first (bench.replay.smooth)
        first = open_log(path)
        try:
            smoothed = smoothing_pass(first, config)
        finally:
            first.close()
    source = open_log(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        summary = SummarySink()
        layout = RESULTS if smoothed is None else SMOOTHED
        out = parquet_sink(target, results_metadata(config, path), layout=layout)
        joined = None if smoothed is None else SmoothedSinks([out], smoothed)
        try:
            outcome = replay(source, config, [joined or out, summary], collect=False)
            if joined is not None:
                joined.check_complete()
            if not outcome.pipeline.stats.frames:  # not "replayed": an error row
                raise no_frames(path, outcome.notices)
        except BaseException:
            abort_all([out])
            raise
        out.close()
    finally:
        source.close()
    row = summary_row(outcome.pipeline.stats, summary)
    row["calibration"] = config.to_toml()
    row["calibration_source"] = config.describe()
    row["result_rows"] = out.rows
    row["smoothed"] = smoothed is not None
    if smoothed is not None:
        row["wheel_diameter_error"] = smoothed.wheel_scale
        row["wheel_diameter_error_sigma"] = smoothed.wheel_scale_sigma
        row.update(per_log_row(smoothed))
    return row
