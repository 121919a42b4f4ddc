"""`bench play LOG -i socketcan -c vcan0` with candump recording the bus (issue 28).

A log the bench wrote (MCAP: 6 s at 100 Hz, 2160 frames, counts from the ICD's rates) and a
candump text log of its frames, each played onto vcan0; candump, an independent reader,
counts every frame and its order and bytes. ``--ids`` and ``--skip-to`` are checked against
the subset computed from the log itself.
"""

from __future__ import annotations

import contextlib
import re
from pathlib import Path

import numpy as np
import pytest

from tests.vcan.support import (
    CHANNEL,
    bench_main,
    candump,
    need,
    per_id,
    read_log_frames,
    stop_candump,
    tool_missing,
    wire,
)

pytestmark = pytest.mark.vcan

SCENARIO = """
description = "vcan: bench play, 6 s at 100 Hz"
seed = 11
duration_s = 6.0
sample_rate_hz = 100
initial_speed_mps = 8.0
[[track]]
length_m = 100.0
gradient_permil = 4.0
"""
EXPECTED_PER_ID = {0x100: 60, 0x101: 600, 0x102: 600, 0x103: 600, 0x180: 300}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    need(tool_missing("candump"))
    tmp = tmp_path_factory.mktemp("play")
    scenario = tmp / "play.toml"
    scenario.write_text(SCENARIO)
    logs = {}
    for suffix in (".mcap", ".log"):
        logs[suffix] = tmp / f"recorded{suffix}"
        assert bench_main("emulate", scenario, "--out", logs[suffix], "-q") == 0
    return logs


def play_under_candump(log: Path, folder: Path, *extra: str) -> tuple[int, str, np.ndarray]:
    """(exit code, the command's output, every frame candump saw on vcan0)."""
    folder.mkdir()
    dump = candump(folder)
    out = folder / "play.out"

    with out.open("w") as f, contextlib.redirect_stdout(f):
        code = bench_main("play", log, "-i", "socketcan", "-c", CHANNEL, "-q", *extra)
    return code, out.read_text(), read_log_frames(stop_candump(dump, folder))


@pytest.mark.parametrize("suffix", [".mcap", ".log"])
def test_candump_sees_every_frame_of_the_log(
    recorded: dict[str, Path], tmp_path: Path, suffix: str
) -> None:
    log = recorded[suffix]
    expected = read_log_frames(log)
    assert dict(per_id(expected)) == EXPECTED_PER_ID  # 2160 frames, by the ICD's rates
    code, out, seen = play_under_candump(log, tmp_path / "dump")
    assert code == 0, out
    assert wire(seen) == wire(expected)  # every frame, in order, byte for byte
    assert "bench: done: 2160 frames sent of 2160 selected (2160 in the log), 0 send errors" in out
    # on the bus (candump's kernel times), no frame ahead of its recorded time after the
    # first: a player that did not pace, or sent its first frames late and then caught up
    # in a burst, breaks this (0.05 s: the first frame's own send)
    bus = seen["t"] - seen["t"][0]
    rec = expected["t"] - expected["t"][0]
    assert (bus >= rec - 0.05).all(), float((rec - bus).max())


def test_ids_and_skip_to_on_vcan(recorded: dict[str, Path], tmp_path: Path) -> None:
    log = recorded[".mcap"]
    frames = read_log_frames(log)
    rel = frames["t"] - frames["t"][0]
    want = frames[(rel >= 3.0) & np.isin(frames["id"], [0x102, 0x180])]
    code, out, seen = play_under_candump(
        log, tmp_path / "dump", "--ids", "102,180", "--skip-to", "3", "--rate", "2"
    )
    assert code == 0, out
    assert wire(seen) == wire(want)
    assert re.search(rf"{len(want)} frames sent of {len(want)} selected \(2160 in the log;", out)
