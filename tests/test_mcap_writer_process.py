"""The MCAP writer process (bench.mcaplog.writer_process): the step transport is lossless,
the file it writes holds exactly what was written to the sink, and its failures are loud
but never reach the caller."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bench.config import Config
from bench.mcaplog.reader import McapLog
from bench.mcaplog.recorded import read_results
from bench.mcaplog.writer_process import McapProcessSink, pack_steps, unpack_steps
from bench.pipeline.steps import Pipeline, StepOutput
from devices.base import SourceBatch, SourceNotice
from devices.emulator import scenario_from_dict, simulate
from protocol.layout import Outcome
from protocol.records import LinkError

FIELDS = ("frames", "outcome", "samples", "results", "events", "status", "speed")


def _steps(seconds: float = 2.0, cut: int = 5) -> list[tuple[StepOutput, int]]:
    """Pipeline steps of an emulated run with faults, cut into batches of ``cut`` frames;
    every 7th batch carries a link error and a notice, every 11th step has no batch."""
    sc = scenario_from_dict(
        {
            "duration_s": seconds,
            "sample_rate_hz": 200,
            "seed": 4,
            "faults": [
                {
                    "kind": "crc",
                    "channel": 2,
                    "start_s": 0.15 * seconds,
                    "end_s": 0.3 * seconds,
                    "probability": 0.5,
                },
                {"kind": "dropout", "channel": 1, "start_s": 0.4 * seconds, "end_s": 0.5 * seconds},
            ],
        }
    )
    frames = simulate(sc).frames
    pipe = Pipeline(Config(sample_rate_hz=200))
    out = []
    for k, i in enumerate(range(0, len(frames), cut)):
        errors = (
            [LinkError(float(k), Outcome.CRC16_ERROR, b"\x00\xff", "test")] if k % 7 == 0 else []
        )
        notices = [SourceNotice(float(k), "parse_error", f"notice {k}")] if k % 7 == 0 else []
        step = pipe.process(SourceBatch(frames[i : i + cut], errors, notices))
        if k % 11 == 0:
            step.batch = None
        out.append((step, 1_000_000_000 + k))
    out.append((pipe.finish(), 2_000_000_000))
    return out


def test_pack_unpack_gives_back_every_step_field_for_field() -> None:
    items = _steps()
    assert any(len(s.results) for s, _ in items) and any(len(s.events) for s, _ in items)
    back = unpack_steps(pack_steps(items))
    assert len(back) == len(items)
    for (a, wa), (b, wb) in zip(items, back, strict=True):
        assert wa == wb and a.seq0 == b.seq0
        for name in FIELDS:
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name
        assert (a.batch is None) == (b.batch is None)
        if a.batch is not None and b.batch is not None:
            assert b.batch.link_errors == a.batch.link_errors
            assert b.batch.notices == a.batch.notices
            assert b.batch.frames.tobytes() == a.batch.frames.tobytes()


def test_pack_of_empty_steps() -> None:
    items = [(StepOutput(), 5), (StepOutput(), 6)]
    back = unpack_steps(pack_steps(items))
    assert [w for _, w in back] == [5, 6]
    assert all(len(getattr(s, n)) == 0 for s, _ in back for n in FIELDS)


def _write_all(sink: McapProcessSink, items: list[tuple[StepOutput, int]]) -> int:
    frames = 0
    for k, (step, _) in enumerate(items):
        sink.write(step)
        frames += len(step.frames)
        if k == len(items) // 2:
            sink.mark(123.5, "half way")
    return frames


def test_the_file_holds_every_frame_result_and_the_mark(tmp_path: Path) -> None:
    items = _steps()
    path = tmp_path / "proc.mcap"
    sink = McapProcessSink(path, Config(sample_rate_hz=200), {"source": "writer test"})
    assert sink.error is None
    frames = _write_all(sink, items)
    sink.close()
    assert sink.error is None and sink.frames_lost == 0 and sink.dropped == 0
    assert sink.frames_logged == frames
    assert sink._proc.poll() == 0
    with McapLog(path) as lg:
        assert lg.complete, lg.warnings
        got, link_errors, notices = lg.read_frames()
        assert lg.metadata_dict()["summary"]["frames_logged"] == str(frames)
        events = lg.json_topic("/bench/events")
    sent = np.concatenate([s.frames for s, _ in items])
    assert got.tobytes() == sent.tobytes()
    assert len(link_errors) == sum(len(s.batch.link_errors) for s, _ in items if s.batch)
    assert len(notices) == sum(len(s.batch.notices) for s, _ in items if s.batch)
    want = np.concatenate([s.results for s, _ in items])
    results = read_results(path)
    assert len(results) == len(want) > 100
    for name in ("n", "gradient", "slopes", "votes", "gradient_signed"):
        assert results[name].tobytes() == want[name].tobytes(), name
    assert any("half way" in str(e) for e in events)


def test_unwritable_path_is_an_error_not_an_exception(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    sink = McapProcessSink(blocker / "run.mcap", Config())
    assert sink.error is not None and "a-file" in sink.error
    frames = _write_all(sink, _steps(0.5))
    sink.close()
    assert sink.frames_logged == 0
    assert sink.frames_lost == frames
    assert sink.status().error == sink.error


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_a_dead_writer_is_reported_and_counted(tmp_path: Path) -> None:
    items = _steps(1.0)
    sink = McapProcessSink(tmp_path / "dies.mcap", Config(sample_rate_hz=200))
    half = len(items) // 2
    for step, _ in items[:half]:
        sink.write(step)
    os.kill(sink._proc.pid, signal.SIGKILL)
    sink._proc.wait(10)
    after = 0
    for step, _ in items[half:]:
        sink.write(step)  # never raises
        after += len(step.frames)
    sink.close()
    assert sink.error is not None and "writer process" in sink.error
    total = sum(len(s.frames) for s, _ in items)
    assert sink.frames_lost >= after
    assert sink.frames_logged + sink.frames_lost == total


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ctrl_c_and_sigterm_do_not_stop_the_writer(tmp_path: Path) -> None:
    items = _steps(1.0)
    path = tmp_path / "signals.mcap"
    sink = McapProcessSink(path, Config(sample_rate_hz=200))
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        os.kill(sink._proc.pid, sig)  # sent to it directly
    time.sleep(0.3)
    assert sink._proc.poll() is None
    frames = _write_all(sink, items)
    sink.close()
    assert sink.error is None and sink.frames_logged == frames
    with McapLog(path) as lg:
        assert lg.complete


def test_log_writer_setting(monkeypatch: pytest.MonkeyPatch) -> None:
    from bench.errors import BenchError
    from bench.live.setup import recording_sink_class
    from bench.mcaplog.sink import McapSink

    monkeypatch.delenv("BENCH_LOG_WRITER", raising=False)
    assert recording_sink_class() is McapProcessSink
    monkeypatch.setenv("BENCH_LOG_WRITER", "thread")
    assert recording_sink_class() is McapSink
    monkeypatch.setenv("BENCH_LOG_WRITER", "fast")
    with pytest.raises(BenchError, match="BENCH_LOG_WRITER must be"):
        recording_sink_class()


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux scheduling classes")
def test_the_writer_runs_at_idle_priority(tmp_path: Path) -> None:
    sink = McapProcessSink(tmp_path / "prio.mcap", Config())
    try:
        assert os.sched_getscheduler(sink._proc.pid) == os.SCHED_IDLE
    finally:
        sink.close()
