"""Crash safety of McapSink in a real process: kill -9 loses at most about one second; a
clean stop (Ctrl-C, SIGTERM turned into a clean shutdown) always writes the summary."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bench.mcaplog.reader import McapLog

ROOT = Path(__file__).resolve().parents[1]

WRITER = r"""
import importlib, signal, sys, time
import numpy as np
sys.path.insert(0, sys.argv[3])
from bench.config import Config
module, name = sys.argv[4].rsplit(".", 1)
McapSink = getattr(importlib.import_module(module), name)
from bench.pipeline.steps import StepOutput
from protocol.frames import FRAME_DTYPE

def on_term(signum, frame):  # what bench run does: SIGTERM -> clean shutdown
    raise KeyboardInterrupt

signal.signal(signal.SIGTERM, on_term)
flush_s = float(sys.argv[2])
sink = McapSink(sys.argv[1], Config(), {"source": "crash test"}, flush_interval_s=flush_s)
k = 0
try:
    with sink:
        print("ready", flush=True)
        while True:  # 2000 frames/s in steps of 20, receive time = wall clock
            fr = np.zeros(20, FRAME_DTYPE)
            fr["t"] = time.time()
            fr["id"] = 0x101
            fr["dlc"] = 8
            fr["data"][:, 0] = np.arange(k, k + 20) & 255
            sink.write(StepOutput(frames=fr, outcome=np.zeros(20, np.uint8)))
            k += 20
            print(repr(float(fr["t"][0])), k, flush=True)
            time.sleep(0.01)
except KeyboardInterrupt:
    pass
print("closed", sink.frames_logged, sink.error, flush=True)
"""


THREAD_SINK = "bench.mcaplog.sink.McapSink"
PROCESS_SINK = "bench.mcaplog.writer_process.McapProcessSink"


def start_writer(
    path: Path, flush_s: float = 0.5, sink: str = THREAD_SINK
) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(path), str(flush_s), str(ROOT), sink],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.strip() == "ready", proc.stderr.read() if proc.stderr else line
    return proc


def sent_lines(out: str) -> list[tuple[float, int]]:
    rows = []
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] not in ("ready", "closed"):
            rows.append((float(parts[0]), int(parts[1])))
    return rows


def sent_for(proc: subprocess.Popen[str], seconds: float) -> str:
    """The writer's lines until it has sent `seconds` of stream (no wall-clock sleep)."""
    assert proc.stdout is not None
    lines: list[str] = []
    first: float | None = None
    for line in proc.stdout:
        lines.append(line)
        rows = sent_lines(line)
        if rows:
            first = rows[0][0] if first is None else first
            if rows[0][0] - first >= seconds:
                break
    return "".join(lines)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_kill_9_loses_at_most_about_a_second(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    proc = start_writer(path)
    early = sent_for(proc, 2.5)
    os.kill(proc.pid, signal.SIGKILL)
    out, _ = proc.communicate(timeout=10)
    out = early + out
    sent = sent_lines(out)
    assert len(sent) > 100
    last_sent_t, total = sent[-1]
    with McapLog(path) as lg:
        assert lg.truncated and not lg.complete  # no summary: it was killed
        frames, _, _ = lg.read_frames()
    assert len(frames) > 0
    lost_s = last_sent_t - float(frames["t"][-1])
    print(f"kill -9: {total - len(frames)} of {total} frames lost ({lost_s:.3f} s)")
    assert lost_s <= 1.0, f"kill -9 lost {lost_s:.2f} s of frames"
    assert total - len(frames) <= 2000 * 1.0 + 20  # at 2000 frames/s
    counters = frames["data"][:, 0]
    assert np.array_equal(counters, np.arange(len(frames)) & 255)  # no holes before the cut


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_kill_9_of_the_bench_leaves_a_finished_file_with_the_writer_process(
    tmp_path: Path,
) -> None:
    """The writer process finishes the file when the bench process's pipe closes: what was
    handed over (all but the last group interval) is in a complete file."""
    path = tmp_path / "killed-parent.mcap"
    proc = start_writer(path, sink=PROCESS_SINK)
    early = sent_for(proc, 2.5)
    os.kill(proc.pid, signal.SIGKILL)
    out, _ = proc.communicate(timeout=10)
    out = early + out
    sent = sent_lines(out)
    last_sent_t, total = sent[-1]
    deadline = time.monotonic() + 20
    while True:
        with McapLog(path) as lg:
            if lg.complete or time.monotonic() > deadline:
                break
        time.sleep(0.2)
    with McapLog(path) as lg:
        assert lg.complete, lg.warnings
        frames, _, _ = lg.read_frames()
    lost_s = last_sent_t - float(frames["t"][-1])
    print(f"kill -9 (writer process): {total - len(frames)} of {total} lost ({lost_s:.3f} s)")
    # what the parent had not yet handed over: a group interval, more on a loaded machine
    # (0.61 s seen at load 6); like the thread writer's, about a second at most
    assert lost_s <= 1.0, f"kill -9 lost {lost_s:.2f} s of frames"
    counters = frames["data"][:, 0]
    assert np.array_equal(counters, np.arange(len(frames)) & 255)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("sink", [THREAD_SINK, PROCESS_SINK])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_clean_stop_writes_the_summary(tmp_path: Path, sig: int, sink: str) -> None:
    path = tmp_path / "stopped.mcap"
    proc = start_writer(path, sink=sink)
    early = sent_for(proc, 1.0)  # a second of stream, however slow the machine
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)  # a hang guard, not a bound
    out = early + out
    assert "closed" in out, err
    total = sent_lines(out)[-1][1]
    with McapLog(path) as lg:
        assert lg.complete, lg.warnings
        frames, _, _ = lg.read_frames()
        assert lg.statistics is not None
        assert lg.metadata_dict()["summary"]["frames_logged"] == str(len(frames))
    assert total <= len(frames) <= total + 20  # everything written before the stop
