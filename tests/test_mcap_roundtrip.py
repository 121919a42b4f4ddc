"""MCAP round trip: what a live run writes through McapSink is what a replay reads back.

Frames in the file = frames received (per ID, bit for bit, in arrival order), link errors
and notices included; replaying the file gives the live run's CSV byte for byte; the
derived topics carry the pipeline's values exactly (floats via repr, NaN via null).
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from bench.config import ChannelCal, Config
from bench.mcaplog import schemas as S
from bench.mcaplog.compare import compare_results
from bench.mcaplog.emulation import write_emulation
from bench.mcaplog.reader import McapLog
from bench.mcaplog.recorded import (
    read_attachments,
    read_events,
    read_frames,
    read_metadata,
    read_results,
    read_samples,
    read_speed,
    read_status,
    read_topic,
    recorded_config,
)
from bench.mcaplog.sink import McapSink
from bench.mcaplog.source import McapFrameSource
from bench.pipeline.steps import StepOutput
from devices.base import SourceBatch
from protocol.frames import FRAME_DTYPE
from protocol.layout import Outcome
from tests.helpers import until
from tests.test_mcap_support import csv_text, emulated, run_pipeline, synthetic_stream, uart_batches


def live_run(path: Path, batches: list[SourceBatch], config: Config | None = None, **kw: object):
    """A run as bench live does it: pipeline steps handed to an McapSink (plus a mark)."""
    cfg = config or Config()
    sink = McapSink(
        path,
        cfg,
        {"source": "test stream", "mode": "test"},
        [("cal.toml", cfg.to_toml().encode())],
        **kw,
    )  # type: ignore[arg-type]
    results, steps = run_pipeline(batches, cfg, [sink])
    last_t = max(float(s.frames["t"][-1]) for s in steps if len(s.frames))
    sink.mark(last_t, "operator saw a bump")
    sink.close()
    return sink, results, steps


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory):
    stream = synthetic_stream(seconds=4.0)
    path = tmp_path_factory.mktemp("mcap") / "live.mcap"
    sink, results, steps = live_run(path, stream.batches)
    return stream, path, sink, results, steps


def test_frames_link_errors_and_notices_round_trip(synthetic) -> None:
    stream, path, sink, _, _ = synthetic
    assert sink.error is None and sink.dropped == 0
    assert sink.frames_logged == len(stream.frames)
    frames, errors, notices = read_frames(path)
    assert frames.dtype == FRAME_DTYPE
    assert frames.tobytes() == stream.frames.tobytes()  # bit for bit, arrival order
    assert errors == stream.link_errors
    assert notices == stream.notices
    assert Counter(frames["id"].tolist()) == stream.counts_by_id()


def test_frame_outcomes_and_sequence_are_recorded(synthetic) -> None:
    stream, path, *_ = synthetic
    steps = synthetic[4]
    live_outcome = np.concatenate([s.outcome for s in steps if len(s.frames)])
    with McapLog(path) as lg:
        recs = np.concatenate([lg.frame_records(c) for c in lg.iter_chunks()])
    assert np.array_equal(recs["payload"]["outcome"], live_outcome)
    assert {Outcome.CRC_MISMATCH, Outcome.WRONG_DLC, Outcome.UNKNOWN_ID} <= set(
        live_outcome.tolist()
    )
    counted = stream.frames["id"] != 0x7FF  # ADC, status, speed frames carry a counter
    assert np.array_equal(recs["sequence"][counted], stream.frames["data"][counted, 0])
    assert np.all(recs["sequence"][~counted] == 0)
    assert np.array_equal(recs["log_time"], np.rint(stream.frames["t"] * 1e9).astype(np.uint64))


def test_replay_of_the_mcap_gives_the_live_csv_byte_for_byte(synthetic) -> None:
    _, path, _, live_results, _ = synthetic
    assert len(live_results) > 700
    source = McapFrameSource(path)
    replayed, _ = run_pipeline(list(source.batches(max_frames=500)), Config())
    source.close()
    assert replayed.tobytes() == live_results.tobytes()
    assert csv_text(replayed) == csv_text(live_results)
    recorded = read_results(path)
    assert recorded.tobytes() == live_results.tobytes()  # JSON floats round-trip exactly
    assert compare_results(recorded, replayed).identical


def test_replay_through_open_log(synthetic) -> None:
    from devices.formats import open_log

    _, path, _, live_results, _ = synthetic
    source = open_log(path)
    assert isinstance(source, McapFrameSource)
    replayed, _ = run_pipeline(list(source.batches()), Config())
    assert csv_text(replayed) == csv_text(live_results)


def test_derived_topics_hold_the_pipeline_values(synthetic) -> None:
    _, path, _, _, steps = synthetic
    cat = lambda name: np.concatenate([getattr(s, name) for s in steps])  # noqa: E731
    assert read_samples(path).tobytes() == cat("samples").tobytes()
    assert read_status(path).tobytes() == cat("status").tobytes()
    assert read_speed(path).tobytes() == cat("speed").tobytes()
    events = read_events(path)
    live_events = cat("events")
    marks = [e for e in events if e["kind_name"] == "MARK"]
    assert len(marks) == 1 and marks[0]["text"] == "operator saw a bump" and marks[0]["level"] == 2
    others = [e for e in events if e["kind_name"] != "MARK"]
    assert len(others) == len(live_events)
    assert [e["kind"] for e in others] == live_events["kind"].tolist()
    assert {e["kind_name"] for e in others} >= {"CRC_ERROR", "LINK_ERROR", "DISCONNECT", "GAP"}
    for e in others[:50]:
        assert e["timestamp"]["sec"] * 10**9 + e["timestamp"]["nsec"] == round(e["t"] * 1e9)
        assert e["message"] and e["name"] == "bench" and e["level"] in (2, 3, 4)
    health = read_topic(path, S.HEALTH_TOPIC)
    assert len(health) >= 3  # ~1 Hz of receive time, plus the final one
    last = health[-1]
    assert last["frames"] == sum(len(s.frames) for s in steps)
    assert [c["channel"] for c in last["channels"]] == [1, 2, 3]
    assert all(c["rate_hz"] > 150 for c in last["channels"])


def test_nan_results_are_null_and_come_back_nan(synthetic) -> None:
    _, path, _, live_results, _ = synthetic
    invalid = ~live_results["valid"]
    assert invalid.any()  # CRC errors and status bits make some rows invalid
    with McapLog(path) as lg:
        raw = [json.loads(bytes(m)) for m in lg.payloads(S.RESULT_TOPIC)]
    row = raw[int(np.flatnonzero(invalid)[0])]
    assert row["gradient"] is None
    recorded = read_results(path)
    assert np.isnan(recorded["gradient"][invalid]).all()
    assert set(raw[0]) >= {"time_s", "n", "a1", "g12", "v1", "w12", "gradient", "valid", "a_ref"}


def test_metadata_attachments_and_config(synthetic) -> None:
    _, path, sink, _, _ = synthetic
    meta = read_metadata(path)
    assert set(meta) == {"run", "config", "summary"}
    assert meta["run"]["source"] == "test stream" and meta["run"]["bench_version"]
    assert meta["summary"]["frames_logged"] == str(sink.frames_logged)
    assert json.loads(meta["summary"]["stats"])["frames"] == sink.frames_logged
    assert read_attachments(path) == {"cal.toml": Config().to_toml().encode()}
    assert recorded_config(path) == Config()


def test_replay_with_another_config_reports_differences(synthetic, tmp_path: Path) -> None:
    _, path, _, live_results, _ = synthetic
    base = Config()
    tilted = Config(channels=(ChannelCal(30.4), base.channels[1], base.channels[2]))
    source = McapFrameSource(path)
    replayed, _ = run_pipeline(list(source.batches()), tilted)
    report = compare_results(read_results(path), replayed)
    assert not report.identical
    names = {c.name for c in report.columns}
    assert {"g12", "g13"} <= names and "a1" not in names and "code1" not in names
    assert report.matched_rows == len(live_results)
    assert "g12" in report.format()


def test_every_emulator_fault_kind_over_uart_frames_in_file_equal_frames_received(
    tmp_path: Path,
) -> None:
    sim = emulated(13.0)
    batches = uart_batches(sim)
    path = tmp_path / "uart.mcap"
    sink, results, steps = live_run(path, batches)
    received = np.concatenate([s.frames for s in steps if len(s.frames)])
    errors = [e for b in batches for e in b.link_errors]
    assert len(errors) > 10 and len(received) > 7000
    frames, read_errors, _ = read_frames(path)
    assert frames.tobytes() == received.tobytes()
    assert read_errors == errors
    with McapLog(path) as lg:
        counts = lg.message_counts()
    assert counts[S.FRAME_TOPIC] == len(received) == sink.frames_logged
    assert counts[S.LINK_ERROR_TOPIC] == len(errors)
    # the live run's own batches come back (exact replay whatever the pipeline does)
    source = McapFrameSource(path, batching="recorded")
    again = list(source.batches())
    assert [len(b.frames) for b in again] == [len(b.frames) for b in batches if len(b.frames)]
    replayed, _ = run_pipeline(again, Config())
    assert csv_text(replayed) == csv_text(results)


def test_log_and_mcap_of_the_same_emulation_replay_identically(tmp_path: Path) -> None:
    from devices.formats import open_log
    from devices.writers import write_candump

    sim = emulated(14.0, seed=11)
    write_candump(tmp_path / "run.log", sim.frames)
    counts = write_emulation(tmp_path / "run.mcap", [sim], sim.scenario)
    assert counts["frames"] == len(sim.frames) and counts["truth"] == len(sim.truth)
    outs = []
    for name in ("run.log", "run.mcap"):
        src = open_log(tmp_path / name)
        res, _ = run_pipeline(list(src.batches()), Config())
        src.close()
        outs.append(csv_text(res))
    assert outs[0] == outs[1] and outs[0].count("\n") > 2000
    truth = read_topic(tmp_path / "run.mcap", S.TRUTH_TOPIC)
    assert len(truth) == len(sim.truth)
    assert truth[5]["gradient_permil"] == float(sim.truth["gradient_permil"][5])


def test_nan_receive_times_get_a_monotonic_substitute(tmp_path: Path) -> None:
    stream = synthetic_stream(seconds=0.5, faults=False)
    frames = stream.frames.copy()
    frames["t"][10:20] = np.nan
    path = tmp_path / "nan.mcap"
    sink = McapSink(path, Config(), {})
    before = time.time_ns()
    sink.write(StepOutput(frames=frames, outcome=np.zeros(len(frames), np.uint8)))
    sink.close()
    back, _, _ = read_frames(path)
    assert back.tobytes() == frames.tobytes()  # NaN kept in the payload
    with McapLog(path) as lg:
        recs = np.concatenate([lg.frame_records(c) for c in lg.iter_chunks()])
    sub = recs["log_time"][10:20]
    assert np.all(sub >= recs["log_time"][9]) and np.all(sub >= before - 10**9)
    assert read_metadata(path)["summary"]["log_time_substituted"] == "10"


def test_write_never_blocks_and_counts_drops(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from bench.mcaplog import encoder as W

    slow = W.MessageEncoder.write_frames
    release = threading.Event()  # the writer is stuck until the test has written everything
    timed_out: list[bool] = []

    def slow_write(self, *a, **k):  # type: ignore[no-untyped-def]
        # a write() that waited for the writer would hold it here until the hang guard expires
        timed_out.append(not release.wait(30))
        return slow(self, *a, **k)

    monkeypatch.setattr(W.MessageEncoder, "write_frames", slow_write)
    stream = synthetic_stream(seconds=1.0, faults=False)
    path = tmp_path / "slow.mcap"
    sink = McapSink(path, Config(), {}, queue_size=2)
    for i in range(0, len(stream.frames), 10):
        sink.write(StepOutput(frames=stream.frames[i : i + 10], outcome=np.zeros(10, np.uint8)))
    release.set()
    sink.close()
    assert not any(timed_out)  # every write() returned while the writer was stuck
    assert sink.dropped > 0
    frames, _, _ = read_frames(path)
    assert len(frames) + sink.dropped == len(stream.frames)
    dropped_events = [e for e in read_events(path) if e["kind_name"] == "DROPPED"]
    assert sum(e["value"] for e in dropped_events) == sink.dropped
    assert read_metadata(path)["summary"]["dropped_frames"] == str(sink.dropped)


def test_unwritable_path_is_recorded_not_raised(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    sink = McapSink(blocker / "run.mcap", Config(), {})
    stream = synthetic_stream(seconds=0.2, faults=False)
    sink.write(StepOutput(frames=stream.frames, outcome=np.zeros(len(stream.frames), np.uint8)))
    sink.mark(0.0, "x")
    sink.close()
    assert sink.error is not None and "run.mcap" in sink.error
    assert sink.frames_lost == len(stream.frames) and sink.frames_logged == 0
    assert any("FAILED" in r.getMessage() for r in caplog.records)


def test_disk_full_midway_keeps_what_was_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from bench.mcaplog import file as W

    real_write_chunk = W.McapFile._write_chunk
    calls = {"n": 0}

    def flaky_write_chunk(self, chunk):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] > 4:
            raise OSError(28, "No space left on device")
        return real_write_chunk(self, chunk)

    monkeypatch.setattr(W.McapFile, "_write_chunk", flaky_write_chunk)
    stream = synthetic_stream(seconds=1.0, faults=False)
    path = tmp_path / "full.mcap"
    sink = McapSink(path, Config(), {}, chunk_size=4096)
    for i in range(0, len(stream.frames), 50):
        sink.write(StepOutput(frames=stream.frames[i : i + 50], outcome=np.zeros(50, np.uint8)))
    sink.close()
    assert sink.error is not None and "No space left" in sink.error
    frames, _, _ = read_frames(path)  # the chunks before the failure are readable
    assert 0 < len(frames) == sink.frames_logged
    assert sink.frames_logged + sink.frames_lost == len(stream.frames)
    assert frames.tobytes() == stream.frames[: len(frames)].tobytes()


def test_chunks_close_at_least_every_flush_interval(tmp_path: Path) -> None:
    stream = synthetic_stream(seconds=1.0, faults=False)
    path = tmp_path / "slowrate.mcap"
    sink = McapSink(path, Config(), {}, flush_interval_s=0.2)
    sink.write(StepOutput(frames=stream.frames[:30], outcome=np.zeros(30, np.uint8)))
    until(lambda: sink.frames_logged >= 30, "the flush timer")  # only it can flush these
    assert sink.frames_logged == 30  # flushed by the timer, not by size or close
    with McapLog(path) as lg:  # readable while the writer is still open
        assert lg.truncated and len(lg.read_frames()[0]) == 30
    sink.close()
    with McapLog(path) as lg:
        assert lg.complete


def test_close_is_idempotent_and_late_writes_do_not_raise(tmp_path: Path) -> None:
    sink = McapSink(tmp_path / "x.mcap", Config(), {})
    sink.close()
    sink.close()
    sink.write(StepOutput())
    sink.mark(math.nan, "late")
    with McapLog(tmp_path / "x.mcap") as lg:
        assert lg.complete and lg.read_frames()[0].size == 0
