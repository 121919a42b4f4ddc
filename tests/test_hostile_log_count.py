"""After the MCAP log fails, the frame count shown is what the file holds (issue 16 item 13).

With the disk full the writer's own count (frames in chunks it reported flushed) and the
file part ways: the thread writer had said 697 while the file held 1 040 frames. The status
line says "log FAILED" while the run goes on, and at the end gives the count read back from
the file; the expectation here is the count the replay reader gets from that file.
"""

from __future__ import annotations

import os
import re
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
from tests.helpers import bench
from tests.test_faults_disk import limit_file_size

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = "seed = 6\nduration_s = 30.0\nsample_rate_hz = 200\n"


def _frames_in(path: Path) -> int:
    from devices.formats import open_log

    return sum(len(b.frames) for b in open_log(path).batches())


@pytest.mark.parametrize("writer", ["thread", "process"])
def test_count_after_a_full_disk_is_the_files(tmp_path: Path, writer: str) -> None:
    sc, mcap = tmp_path / "s.toml", tmp_path / "run.mcap"
    sc.write_text(SCENARIO)
    proc = bench(
        *["run", "--emulate", str(sc), "--mcap", str(mcap), "--duration", "4"],
        preexec_fn=limit_file_size,
        env={**os.environ, "BENCH_LOG_WRITER": writer},
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


def test_count_after_the_writer_is_killed_is_the_files(tmp_path: Path) -> None:
    """kill -9 of the MCAP writer process mid-run: it had flushed more than it reported
    (1 080 said, 1 442 in the file when this was written)."""
    sc, mcap = tmp_path / "s.toml", tmp_path / "run.mcap"
    sc.write_text(SCENARIO)
    cmd = [sys.executable, "-m", "bench", "run", "--emulate", str(sc), "--mcap", str(mcap)]
    cmd += ["--duration", "5", "--status-every", "0.25"]
    env = {**os.environ, "BENCH_LOG_WRITER": "process"}
    proc = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, text=True, env=env)
    assert proc.stderr is not None
    lines = []
    for line in proc.stderr:  # wait until the writer has reported frames, then kill it
        lines.append(line)
        m = re.search(r" log (\d+)f$", line.rstrip())
        if m and int(m.group(1)) > 300:
            break
    writers = []
    for task in Path(f"/proc/{proc.pid}/task").iterdir():
        for pid in (task / "children").read_text().split():
            if "writer_process" in Path(f"/proc/{pid}/cmdline").read_text():
                writers.append(int(pid))
    assert writers, "".join(lines)
    for pid in writers:
        os.kill(pid, signal.SIGKILL)
    rest = proc.stderr.read()
    assert proc.wait(120) != 0
    err = "".join(lines) + rest
    assert "Traceback" not in err
    held = _frames_in(mcap)
    status = [line for line in err.splitlines() if " frames " in line and "/s" in line]
    assert re.search(rf" log FAILED {held}f in file$", status[-1]), (status[-1], held)
    assert f"(the file holds {held} frames, " in err


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
        model=None,  # a run without the live model (--lag)
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


def test_tui_recording_that_failed_keeps_the_files_count(tmp_path: Path) -> None:
    """The TUI's last-recording status after a failure: the count read back from the cut
    file, not the writer's (here a fake writer that says 7)."""
    from bench.live.session import Recorder
    from bench.mcaplog.emulation import write_emulation
    from devices.emulator import scenario_from_dict
    from devices.emulator.stream import simulate_chunks

    whole = tmp_path / "whole.mcap"
    sc = scenario_from_dict({"duration_s": 20.0, "sample_rate_hz": 200, "seed": 3})
    sent = write_emulation(whole, simulate_chunks(sc, chunk_s=0.5), sc, chunk_size=8192)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    held = _frames_in(cut)
    assert 0 < held < sent["frames"]

    class FailedSink:
        path, error = str(cut), f"{cut}: No space left on device"

        def status(self) -> RecordingStatus:
            return RecordingStatus(path=self.path, frames=7, error=self.error)

        def close(self) -> None:
            pass

    rec = Recorder(sink=FailedSink())
    rec.close()
    assert rec.last_status is not None and rec.last_status.file_frames == held
    assert f"{held} frames in the file" in _figures(rec.last_status)
    assert " 7 frames" not in _figures(rec.last_status)
