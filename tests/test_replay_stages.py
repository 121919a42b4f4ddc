"""A replay runs the pipeline's two stages in two threads (bench.replay.run): the first
(decode, assembly, the reference method) goes on while the estimator is built, the second
completes each step in order. The rows, events and counts are those of Pipeline.process
step by step, a failure on either side ends the replay with that failure, and no stage's
thread outlives it (issue 29)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

import bench.replay.run as replay_run
from bench.config import Config
from bench.pipeline.steps import STEP_ARRAYS, Pipeline, StepOutput
from bench.replay.run import replay, run_steps
from devices.formats import open_log
from devices.writers import write_candump
from tests.test_pipeline_batching import faulty_frames

RATE = 500


class Steps:
    """A sink that keeps every step it is given."""

    def __init__(self) -> None:
        self.steps: list[StepOutput] = []

    def write(self, step: StepOutput) -> None:
        self.steps.append(step)

    def mark(self, t: float, text: str) -> None:
        pass

    def close(self) -> None:
        pass


@pytest.fixture(scope="module")
def faulty_log(tmp_path_factory: pytest.TempPathFactory) -> str:
    path = tmp_path_factory.mktemp("stages") / "faulty.log"
    write_candump(path, faulty_frames(RATE, 3))
    return str(path)


def _stage_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "read-ahead"]


def _none_left(before: list[threading.Thread]) -> bool:
    deadline = time.monotonic() + 30.0  # a loaded machine: the readers see the stop in time
    while time.monotonic() < deadline:
        if not [t for t in _stage_threads() if t not in before and t.is_alive()]:
            return True
        time.sleep(0.05)
    return False


def test_the_two_stages_give_the_steps_of_pipeline_process(faulty_log: str) -> None:
    config = Config(sample_rate_hz=RATE)
    source = open_log(faulty_log)
    alone = Pipeline(config)
    expected = list(run_steps(alone, source.batches(512)))
    source.close()
    sink = Steps()
    source = open_log(faulty_log)
    outcome = replay(source, config, [sink], batch_frames=512)
    source.close()
    # more steps than the stages hold between them: the first stage waited for the second
    assert len(sink.steps) == len(expected) > replay_run.REFERENCED_AHEAD + replay_run.READ_AHEAD
    for got, want in zip(sink.steps, expected, strict=True):
        for name in STEP_ARRAYS:
            assert getattr(got, name).tobytes() == getattr(want, name).tobytes(), name
        assert got.seq0 == want.seq0
    assert outcome.results.tobytes() == np.concatenate([s.results for s in expected]).tobytes()
    assert outcome.pipeline.stats.as_dict() == alone.stats.as_dict()
    assert outcome.pipeline.stats.events == alone.stats.events
    assert len(outcome.results) and np.isfinite(outcome.results["gradient_signed"]).any()


def test_the_first_stage_runs_while_the_estimator_is_built(
    faulty_log: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    referenced = threading.Event()
    first_stage = Pipeline.reference

    def reference(self: Pipeline, batch: object) -> object:
        out = first_stage(self, batch)  # type: ignore[arg-type]
        referenced.set()
        return out

    seen_before_build = []

    def new_estimator(config: Config) -> object:
        seen_before_build.append(referenced.wait(30.0))
        return real_new_estimator(config)

    real_new_estimator = replay_run.new_estimator
    monkeypatch.setattr(Pipeline, "reference", reference)
    monkeypatch.setattr(replay_run, "new_estimator", new_estimator)
    source = open_log(faulty_log)
    outcome = replay(source, Config(sample_rate_hz=RATE), batch_frames=1024)
    source.close()
    assert seen_before_build == [True]
    assert outcome.pipeline.stats.frames > 0


def test_a_sink_failure_ends_the_replay_and_its_stages(faulty_log: str) -> None:
    class Failing(Steps):
        def write(self, step: StepOutput) -> None:
            super().write(step)
            if len(self.steps) == 3:
                raise OSError(28, "No space left on device")

    before = _stage_threads()
    sink = Failing()
    source = open_log(faulty_log)
    with pytest.raises(OSError, match="No space left"):
        replay(source, Config(sample_rate_hz=RATE), [sink], batch_frames=1024)
    source.close()
    assert len(sink.steps) == 3  # nothing written after the failure
    assert _none_left(before)


def test_a_first_stage_failure_ends_the_replay_after_the_steps_before_it(
    faulty_log: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = []
    first_stage = Pipeline.reference

    def reference(self: Pipeline, batch: object) -> object:
        calls.append(1)
        if len(calls) == 4:
            raise MemoryError("the fourth batch")
        return first_stage(self, batch)  # type: ignore[arg-type]

    monkeypatch.setattr(Pipeline, "reference", reference)
    before = _stage_threads()
    sink = Steps()
    source = open_log(faulty_log)
    with pytest.raises(MemoryError, match="the fourth batch"):
        replay(source, Config(sample_rate_hz=RATE), [sink], batch_frames=1024)
    source.close()
    assert len(sink.steps) == 3  # the three steps before it, completed and written
    assert _none_left(before)


def test_the_first_step_is_cut_short_and_the_rows_are_those_of_the_uncut_batches(
    faulty_log: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The log's first batch is cut after FIRST_STEP_FRAMES frames (the first frames are
    processed sooner); every array of the steps taken together, and the counts, are those
    of Pipeline.process over the batches as the log gives them."""
    monkeypatch.setattr(replay_run, "FIRST_STEP_FRAMES", 1000)
    config = Config(sample_rate_hz=RATE)
    source = open_log(faulty_log)
    batches = list(source.batches(4096))
    source.close()
    alone = Pipeline(config)
    expected = list(run_steps(alone, batches))
    sink = Steps()
    source = open_log(faulty_log)
    outcome = replay(source, config, [sink], batch_frames=4096)
    source.close()
    sizes = [len(s.frames) for s in sink.steps]
    assert sizes[:2] == [1000, len(batches[0].frames) - 1000]
    assert sizes[2:] == [len(s.frames) for s in expected[1:]]
    assert [s.seq0 for s in sink.steps[:2]] == [0, 1000]
    for name in STEP_ARRAYS:
        if name == "events":  # a step's events go by kind (bench.pipeline.steps): a step
            continue  # cut in two has the same events in another order; sorted below
        got = b"".join(getattr(s, name).tobytes() for s in sink.steps)
        assert got == b"".join(getattr(s, name).tobytes() for s in expected), name
    got_events = np.sort(np.concatenate([s.events for s in sink.steps]))
    want_events = np.sort(np.concatenate([s.events for s in expected]))
    assert len(want_events) > 10 and got_events.tobytes() == want_events.tobytes()
    assert outcome.pipeline.stats.as_dict() == alone.stats.as_dict()
    assert outcome.pipeline.stats.events == alone.stats.events


def test_a_first_batch_with_notices_or_few_frames_is_not_cut() -> None:
    from devices.base import SourceBatch, SourceNotice
    from protocol.frames import empty_frames

    def batch(n: int, notices: int = 0) -> SourceBatch:
        frames = np.zeros(n, dtype=empty_frames().dtype)
        frames["t"] = np.arange(n)
        return SourceBatch(frames, [], [SourceNotice(0.0, "parse_error", "x")] * notices)

    cut = list(replay_run.first_cut([batch(10), batch(7)], 4))
    assert [len(b.frames) for b in cut] == [4, 6, 7]
    assert cut[1].frames["t"].tolist() == [4, 5, 6, 7, 8, 9]
    assert [len(b.frames) for b in replay_run.first_cut([batch(4), batch(9)], 4)] == [4, 9]
    kept = list(replay_run.first_cut([batch(10, notices=1), batch(9)], 4))
    assert [(len(b.frames), len(b.notices)) for b in kept] == [(10, 1), (9, 0)]
    assert list(replay_run.first_cut([], 4)) == []
