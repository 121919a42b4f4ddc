"""An emulator run straight to an MCAP file (``bench emulate --out run.mcap``): frames and
truth, with the scenario attached. A batch job, not an acquisition path."""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import Config
from bench.mcaplog import schemas as S
from bench.mcaplog.encoder import MessageEncoder, config_record, run_record
from bench.mcaplog.file import DEFAULT_CHUNK_SIZE, McapFile, utc_now
from protocol.batch import decode_batch
from protocol.layout import DEFAULT_BASE


def write_emulation(
    path: str | Path,
    chunks: Iterable[Any],
    scenario: Any,
    scenario_path: str | Path | None = None,
    *,
    config: Config | None = None,
    metadata: Mapping[str, str] | None = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
) -> dict[str, int]:
    """Write an emulator run that comes in chunks (each with ``frames``, FRAME_DTYPE, and
    ``truth``, TRUTH_DTYPE: :func:`devices.emulator.stream.simulate_chunks`, or a whole
    ``Simulation`` as one chunk) to MCAP, each chunk's frames, then its truth, so the run
    is never in memory whole; the scenario file attached. Returns counts (frames, truth,
    bytes)."""
    from devices.emulator.engine import TRUTH_DTYPE

    truth_cols = S.columns_for(TRUTH_DTYPE)
    base_id = int(getattr(scenario, "base_id", DEFAULT_BASE))
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
        if getattr(scenario, "seed", None) is not None:
            run["seed"] = str(scenario.seed)
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
        enc = MessageEncoder(mf, base_id, [S.truth_topic(truth_cols)])
        step = 65536
        for chunk in chunks:
            frames, truth = chunk.frames, chunk.truth
            outcome = decode_batch(frames, base_id).outcome
            for start in range(0, len(frames), step):
                enc.write_frames(frames[start : start + step], outcome[start : start + step], wall)
                mf.maybe_flush()
            n_frames += len(frames)
            ids, counts = np.unique(frames["id"], return_counts=True)
            by_id.update(dict(zip(ids.tolist(), counts.tolist(), strict=True)))
            for start in range(0, len(truth), step):
                rows = truth[start : start + step]
                enc.write_truth(rows, truth_cols, rows["time_s"], wall)
                mf.maybe_flush()
            n_truth += len(truth)
        mf.flush_chunk()
        mf.add_metadata(
            "summary",
            {
                "stopped_utc": utc_now(),
                "frames": str(n_frames),
                "frames_logged": str(n_frames),
                "frames_by_id": json.dumps({f"0x{k:03X}": v for k, v in sorted(by_id.items())}),
                "link_errors": "0",
                "truth_rows": str(n_truth),
                "log_time_substituted": str(enc.substituted),
            },
        )
        mf.finish()
    except BaseException:
        mf.abort()
        raise
    return {"frames": n_frames, "truth": n_truth, "bytes": mf.position}
