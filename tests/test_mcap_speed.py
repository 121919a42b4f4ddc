"""Throughput of the raw-frame path: the writer encodes and the reader gathers frames with
numpy, not per message. Floors are far below the measured rates (docs/MCAP.md) so a slow CI
machine passes, yet a per-message Python loop (~0.1 M frames/s) would fail them."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bench.mcaplog.writer import McapFile, MessageEncoder
from devices.mcap_file import McapFrameSource
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


def test_frame_write_and_read_throughput(tmp_path: Path) -> None:
    frames = big_frames()
    outcome = np.zeros(len(frames), np.uint8)
    path = tmp_path / "big.mcap"
    t0 = time.perf_counter()
    mf = McapFile(path)
    enc = MessageEncoder(mf)
    for i in range(0, len(frames), 65536):
        enc.write_frames(frames[i : i + 65536], outcome[i : i + 65536], 0)
        mf.maybe_flush()
    mf.finish()
    write_rate = len(frames) / (time.perf_counter() - t0)

    t0 = time.perf_counter()
    source = McapFrameSource(path)
    got = [b.frames for b in source.batches()]
    read_rate = len(frames) / (time.perf_counter() - t0)
    source.close()
    print(f"MCAP frames: write {write_rate / 1e6:.2f} M/s, read {read_rate / 1e6:.2f} M/s")
    assert np.concatenate(got).tobytes() == frames.tobytes()
    assert read_rate > 0.6e6
    assert write_rate > 0.3e6
