"""After the MCAP log fails, the frame count shown is what the file holds (issue 16 item 13).

With the disk full the writer's own count (frames in chunks it reported flushed) and the
file part ways: the thread writer had said 697 while the file held 1 040 frames. The status
line says "log FAILED" while the run goes on, and at the end gives the count read back from
the file; the expectation here is the count the replay reader gets from that file.
"""

from __future__ import annotations

import os
import re
import resource
import signal
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from bench.commands.run import status_line
from bench.sinks.base import RecordingStatus
from bench.tui.panels.recording import _figures

ROOT = Path(__file__).resolve().parent.parent
LIMIT = 60_000
SCENARIO = "seed = 6\nduration_s = 30.0\nsample_rate_hz = 200\n"


def _limit_file_size() -> None:  # in the child, between fork and exec
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


def _frames_in(path: Path) -> int:
    from bench.replay.sources import open_replay

    return sum(len(b.frames) for b in open_replay(path).batches())


@pytest.mark.parametrize("writer", ["thread", "process"])
def test_count_after_a_full_disk_is_the_files(tmp_path: Path, writer: str) -> None:
    sc, mcap = tmp_path / "s.toml", tmp_path / "run.mcap"
    sc.write_text(SCENARIO)
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "bench",
            "run",
            "--emulate",
            str(sc),
            "--mcap",
            str(mcap),
            "--duration",
            "4",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=_limit_file_size,
        env={**os.environ, "BENCH_LOG_WRITER": writer},
        check=False,
    )
    assert "Traceback" not in proc.stderr and proc.returncode != 0, proc.stderr
    held = _frames_in(mcap)
    assert held > 0
    status = [line for line in proc.stderr.splitlines() if " frames " in line and "/s" in line]
    assert status, proc.stderr
    assert re.search(rf" log FAILED {held}f in file$", status[-1]), (status[-1], held)
    for line in status[:-1]:  # while the run goes on no writer count is shown
        assert re.search(r" log (FAILED$|\d+f$)", line), line
    assert f"(the file holds {held} frames, " in proc.stderr


def _snapshot(rec: RecordingStatus) -> Any:
    """What status_line reads of a Snapshot."""
    from bench.pipeline.stats import Stats

    return SimpleNamespace(
        stats=Stats(),
        results=[],
        frames_received=10,
        frames_dropped=0,
        recording=rec,
        output_errors=[],
    )


def test_status_line_shows_no_writer_count_after_a_failure() -> None:
    failed = RecordingStatus(path="x.mcap", frames=10_492, error="x.mcap: No space left")
    line = status_line(_snapshot(failed), 1.0)
    assert line.endswith(" log FAILED") and "10492" not in line
    assert "10492" not in _figures(failed)
    known = RecordingStatus(path="x.mcap", frames=10_492, error="boom", file_frames=10_667)
    assert status_line(_snapshot(known), 1.0).endswith(" log FAILED 10667f in file")
    assert "10667 frames in the file" in _figures(known)
    fine = RecordingStatus(path="x.mcap", frames=5)
    assert status_line(_snapshot(fine), 1.0).endswith(" log 5f")
