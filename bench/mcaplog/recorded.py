"""What a recording holds, as the bench's rows and records: each function takes a path or an
opened :class:`~bench.mcaplog.reader.McapLog`."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import ORIGINS, Config, config_from_dict
from bench.errors import BenchError
from bench.mcaplog import schemas as S
from bench.mcaplog.reader import McapLog
from bench.records.board import SPEED_DTYPE, STATUS_DTYPE
from bench.records.model import MODEL_DTYPE
from bench.records.results import RESULT_DTYPE
from bench.records.samples import SAMPLE_DTYPE
from devices.base import SourceNotice
from protocol.records import LinkError


def _with(source: str | Path | McapLog, fn: Any) -> Any:
    if isinstance(source, McapLog):
        return fn(source)
    with McapLog(source) as lg:
        return fn(lg)


def read_frames(
    source: str | Path | McapLog,
) -> tuple[np.ndarray, list[LinkError], list[SourceNotice]]:
    """Every raw frame (FRAME_DTYPE, arrival order), link error and recorded notice."""
    return _with(source, lambda lg: lg.read_frames())


def count_frames(path: str | Path) -> int | None:
    """How many frames a log file holds, cut or not (every complete chunk counts); None
    when it cannot be read. What a failed recording is reported to hold."""
    try:
        with McapLog(path) as lg:
            if lg.channel_id(S.FRAME_TOPIC) is None:
                return 0
            return sum(len(lg.frame_records(c)) for c in lg.iter_chunks())
    except Exception:  # a file that cannot be read at all: its count is unknown
        return None


def read_results(source: str | Path | McapLog) -> np.ndarray:
    """The recorded fusion results (RESULT_DTYPE), as the live run computed them."""
    return _with(source, lambda lg: lg.table(S.RESULT_TOPIC, S.RESULT_COLUMNS, RESULT_DTYPE))


def read_samples(source: str | Path | McapLog) -> np.ndarray:
    return _with(source, lambda lg: lg.table(S.SAMPLE_TOPIC, S.SAMPLE_COLUMNS, SAMPLE_DTYPE))


def read_status(source: str | Path | McapLog) -> np.ndarray:
    return _with(source, lambda lg: lg.table(S.STATUS_TOPIC, S.STATUS_COLUMNS, STATUS_DTYPE))


def read_speed(source: str | Path | McapLog) -> np.ndarray:
    return _with(source, lambda lg: lg.table(S.SPEED_TOPIC, S.SPEED_COLUMNS, SPEED_DTYPE))


def read_model(source: str | Path | McapLog) -> np.ndarray:
    """The live model's rows (MODEL_DTYPE, `--lag`); none in a run without the model."""
    return _with(source, lambda lg: lg.table(S.MODEL_TOPIC, S.MODEL_COLUMNS, MODEL_DTYPE))


def read_events(source: str | Path | McapLog) -> list[dict[str, Any]]:
    """Recorded events as foxglove.Log objects (with t, kind, channel, n, value, text)."""
    return _with(source, lambda lg: lg.json_topic(S.EVENT_TOPIC))


def read_topic(source: str | Path | McapLog, topic: str) -> list[dict[str, Any]]:
    return _with(source, lambda lg: lg.json_topic(topic))


def read_metadata(source: str | Path | McapLog) -> dict[str, dict[str, str]]:
    return _with(source, lambda lg: lg.metadata_dict())


def read_attachments(source: str | Path | McapLog) -> dict[str, bytes]:
    return _with(source, lambda lg: {a.name: lg.attachment(a.name) or b"" for a in lg.attachments})


def recorded_config(source: str | Path | McapLog) -> Config | None:
    """The config the run used (``config`` metadata record), or None if none was recorded.
    Raises ConfigError if the recorded TOML is not a valid config."""

    def get(lg: McapLog) -> Config | None:
        meta = lg.metadata_dict().get("config")
        if not meta or "toml" not in meta:
            return None
        where = f"{lg.path.name}:config"
        try:
            data = tomllib.loads(meta["toml"])
        except tomllib.TOMLDecodeError as exc:
            raise BenchError(f"{where}: recorded config is not valid TOML: {exc}") from None
        origin = meta.get("origin", "file")
        cfg = config_from_dict(
            data,
            source=meta.get("source", where),
            path=meta.get("path"),
            origin=origin if origin in ORIGINS else "file",
        )
        return replace(cfg, recorded_in=lg.path.name)

    return _with(source, get)
