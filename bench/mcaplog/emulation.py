"""An emulator run straight to an MCAP file (``bench emulate --out run.mcap``): frames, link
errors and truth, with the scenario attached. A batch job, not an acquisition path."""

from __future__ import annotations

import json
import math
import time
from collections import Counter
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import Config
from bench.mcaplog import schemas as S
from bench.mcaplog.encoder import MessageEncoder, config_record, run_record
from bench.mcaplog.file import DEFAULT_CHUNK_SIZE, McapFile, utc_now
from protocol.batch import decode_batch
from protocol.frames import FRAME_DTYPE, frames_from_raw
from protocol.layout import DEFAULT_BASE


def _as_frames(frames: Any) -> np.ndarray:
    if isinstance(frames, np.ndarray) and frames.dtype == FRAME_DTYPE:
        return frames
    if (
        isinstance(frames, np.ndarray)
        and frames.dtype.names
        and set(FRAME_DTYPE.names or ()) <= set(frames.dtype.names)
    ):
        out = np.zeros(len(frames), dtype=FRAME_DTYPE)
        for name in FRAME_DTYPE.names or ():
            out[name] = frames[name]
        return out
    return frames_from_raw(frames)


def _as_table(truth: Any) -> np.ndarray | None:
    """A structured array from a truth table (structured array, dict of columns, or an
    object with a ``to_records``/``as_array`` method); None if it is none of these."""
    if truth is None:
        return None
    if isinstance(truth, np.ndarray) and truth.dtype.names:
        return truth
    for attr in ("as_array", "to_array", "to_records"):
        fn = getattr(truth, attr, None)
        if callable(fn):
            arr = np.asarray(fn())
            return arr if arr.dtype.names else None
    cols = truth if isinstance(truth, Mapping) else getattr(truth, "__dict__", None)
    if not isinstance(cols, Mapping):
        return None
    arrays = {k: np.asarray(v) for k, v in cols.items() if isinstance(v, np.ndarray | list | tuple)}
    arrays = {k: v for k, v in arrays.items() if v.ndim >= 1 and v.dtype.kind in "biuf"}
    if not arrays:
        return None
    n = len(next(iter(arrays.values())))
    arrays = {k: v for k, v in arrays.items() if len(v) == n}
    out = np.zeros(n, dtype=[(k, v.dtype, v.shape[1:]) for k, v in arrays.items()])
    for k, v in arrays.items():
        out[k] = v
    return out


def _time_column(rows: np.ndarray) -> np.ndarray:
    for name in ("t", "time", "time_s"):
        if rows.dtype.names and name in rows.dtype.names and rows.dtype[name].shape == ():
            return rows[name].astype(np.float64)
    return np.full(len(rows), np.nan)


def write_emulation(
    path: str | Path,
    emulation: Any,
    scenario_path: str | Path | None = None,
    *,
    config: Config | None = None,
    metadata: Mapping[str, str] | None = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
) -> dict[str, int]:
    """Write an emulator run (``emulation.frames`` and, if present, ``.link_errors`` and
    ``.truth``) straight to MCAP, with the scenario file attached. Synchronous: this is a
    batch job, not an acquisition path. Returns counts (frames, link_errors, truth, bytes).
    """
    frames = _as_frames(emulation.frames)
    link_errors = sorted(
        getattr(emulation, "link_errors", None) or [], key=lambda e: (math.isnan(e.t), e.t)
    )
    truth = _as_table(getattr(emulation, "truth", None))
    return _write(
        path,
        iter([(frames, truth)]),
        truth.dtype if truth is not None else None,
        link_errors,
        getattr(emulation, "scenario", None),
        getattr(emulation, "seed", None),
        int(getattr(emulation, "base_id", DEFAULT_BASE)),
        scenario_path,
        config,
        metadata,
        chunk_size,
    )


def write_emulation_chunks(
    path: str | Path,
    chunks: Iterator[Any],
    scenario: Any,
    scenario_path: str | Path | None = None,
    *,
    config: Config | None = None,
    metadata: Mapping[str, str] | None = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
) -> dict[str, int]:
    """:func:`write_emulation` for a run that comes in chunks (each with ``frames`` and
    ``truth``, e.g. :func:`devices.emulator.stream.simulate_chunks`): each chunk's frames,
    then its truth, so the run is never in memory whole."""
    from devices.emulator.engine import TRUTH_DTYPE

    parts = ((_as_frames(c.frames), c.truth) for c in chunks)
    base_id = int(getattr(scenario, "base_id", DEFAULT_BASE))
    return _write(
        path,
        parts,
        TRUTH_DTYPE,
        [],
        scenario,
        None,
        base_id,
        scenario_path,
        config,
        metadata,
        chunk_size,
    )


def _with_last(items: Iterator[Any]) -> Iterator[tuple[Any, bool]]:
    """Each item with whether it is the last one."""
    prev, have = None, False
    for item in items:
        if have:
            yield prev, False
        prev, have = item, True
    if have:
        yield prev, True


def _write(
    path: str | Path,
    parts: Iterator[tuple[np.ndarray, np.ndarray | None]],
    truth_dtype: np.dtype | None,
    link_errors: list[Any],
    scenario: Any,
    seed: Any,
    base_id: int,
    scenario_path: str | Path | None,
    config: Config | None,
    metadata: Mapping[str, str] | None,
    chunk_size: int,
) -> dict[str, int]:
    truth_cols = S.columns_for(truth_dtype) if truth_dtype is not None else []
    if config is not None:
        base_id = config.base_id
    wall = time.time_ns()
    mf = McapFile(path, chunk_size=chunk_size)
    n_frames = n_truth = 0
    by_id: Counter[int] = Counter()
    try:
        run = {"source": "emulator", "mode": "emulate"}
        scen_bytes = b""
        if scenario_path is not None:
            sp = Path(scenario_path)
            scen_bytes = sp.read_bytes()
            run["scenario"] = sp.name
        seed = seed if seed is not None else getattr(scenario, "seed", None)
        if seed is not None:
            run["seed"] = str(seed)
        if getattr(scenario, "description", ""):
            run["scenario_description"] = str(scenario.description)
        run.update(metadata or {})
        mf.add_metadata("run", run_record(run))
        if config is not None:
            mf.add_metadata("config", config_record(config))
        if scenario_path is not None:
            mf.add_metadata(
                "scenario",
                {  # the text as TOML reads it: an editor's byte-order mark is no part of it
                    "path": str(scenario_path),
                    "toml": scen_bytes.decode("utf-8", "replace").removeprefix("\ufeff"),
                },
            )
            mf.add_attachment(Path(scenario_path).name, scen_bytes, log_time=wall)
        topics = [S.truth_topic(truth_cols)] if truth_dtype is not None else []
        enc = MessageEncoder(mf, base_id, topics)
        le_t = np.array([e.t for e in link_errors], dtype=np.float64)
        le_done = 0
        step = 65536
        for (frames, truth), final in _with_last(parts):
            outcome = decode_batch(frames, base_id).outcome
            for start in range(0, len(frames), step):
                part = frames[start : start + step]
                enc.write_frames(part, outcome[start : start + step], wall)
                if final and start + step >= len(frames):
                    upto = len(link_errors)  # the rest go before the truth
                else:
                    upto = int(np.searchsorted(le_t, part["t"][-1], side="right"))
                if upto > le_done:
                    enc.write_link_errors(link_errors[le_done:upto], wall)
                    le_done = upto
                mf.maybe_flush()
            n_frames += len(frames)
            ids, counts = np.unique(frames["id"], return_counts=True)
            by_id.update(dict(zip(ids.tolist(), counts.tolist(), strict=True)))
            if truth is not None:
                t = _time_column(truth)
                for start in range(0, len(truth), step):
                    enc.write_truth(
                        truth[start : start + step], truth_cols, t[start : start + step], wall
                    )
                    mf.maybe_flush()
                n_truth += len(truth)
        if le_done < len(link_errors):
            enc.write_link_errors(link_errors[le_done:], wall)
        mf.flush_chunk()
        mf.add_metadata(
            "summary",
            {
                "stopped_utc": utc_now(),
                "frames": str(n_frames),
                "frames_logged": str(n_frames),
                "frames_by_id": json.dumps({f"0x{k:03X}": v for k, v in sorted(by_id.items())}),
                "link_errors": str(len(link_errors)),
                "truth_rows": str(n_truth if truth_dtype is not None else 0),
                "log_time_substituted": str(enc.substituted),
            },
        )
        mf.finish()
    except BaseException:
        mf.abort()
        raise
    return {
        "frames": n_frames,
        "link_errors": len(link_errors),
        "truth": n_truth if truth_dtype is not None else 0,
        "bytes": mf.position,
    }
