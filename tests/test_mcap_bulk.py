"""The bulk raw-frame path: a million frames written in pipeline-sized blocks come back byte
for byte. (How fast is measured in benchmarks/replay.py, not asserted here.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.mcaplog.encoder import MessageEncoder
from bench.mcaplog.file import McapFile
from bench.mcaplog.source import McapFrameSource
from protocol.frames import FRAME_DTYPE

N = 1_000_000


def big_frames(n: int = N) -> np.ndarray:
    rng = np.random.default_rng(3)
    fr = np.zeros(n, FRAME_DTYPE)
    fr["t"] = 1.7e9 + np.arange(n) / 3000.0
    fr["id"] = rng.choice([0x100, 0x101, 0x102, 0x103, 0x180], n)
    fr["dlc"] = 8
    fr["data"] = rng.integers(0, 256, (n, 8), dtype=np.uint8)
    return fr


def test_a_million_frames_round_trip_in_blocks(tmp_path: Path) -> None:
    frames = big_frames()
    outcome = np.zeros(len(frames), np.uint8)
    path = tmp_path / "big.mcap"
    mf = McapFile(path)
    enc = MessageEncoder(mf)
    for i in range(0, len(frames), 65536):
        enc.write_frames(frames[i : i + 65536], outcome[i : i + 65536], 0)
        mf.maybe_flush()
    mf.finish()

    source = McapFrameSource(path)
    got = [b.frames for b in source.batches()]
    source.close()
    assert sum(len(g) for g in got) == len(frames)
    assert np.concatenate(got).tobytes() == frames.tobytes()
