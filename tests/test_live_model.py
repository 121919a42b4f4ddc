"""The explicit model live (issue 26, `--lag`): `bench run --lag` logs the model's rows on
/bench/model, the same bits a replay of that log gives (whatever the live batching was),
read by @mcap/core; a full queue drops pushes, counted, and never waits; the TUI shows the
model's panel and lagged line only when the run has the model (tests/test_tui_model.py).

Expectations are independent of the live path: the replay's pipeline over the recorded
frames, fed to the model in one push (the ModelLog path `replay --smooth` uses); values
written by hand into the view for the panel's text.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.config_choice import replay_config
from bench.fusion.model import state
from bench.fusion.model.log import gradient_permil
from bench.live.model import LiveModel
from bench.mcaplog import schemas as S
from bench.mcaplog.recorded import read_model
from bench.pipeline.steps import Pipeline
from bench.replay.run import run_steps
from devices.formats import open_log
from tests.mcap_js import McapJs, install
from tests.test_model_stream import _Pushes, _stream, _whole

LAG_S = 0.5
SCENARIO = """
description = "a start and a cruise on a 12 permil grade, the wheel 1 % off"
seed = 5
duration_s = 6.0
sample_rate_hz = 200
speed_ref = true
initial_speed_mps = 5.0
track = [{ length_m = 1000.0, gradient_permil = 12.0 }]
train = [{ duration_s = 3.0, accel_mps2 = 0.6 }, { duration_s = 3.0 }]
[odometer]
wheel_diameter_error = 0.01
"""


@pytest.fixture(scope="module")
def live_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("live_model")
    (d / "s.toml").write_text(SCENARIO)
    log = d / "run.mcap"
    args = ["run", "--emulate", str(d / "s.toml"), "--mcap", str(log), "--lag", str(LAG_S), "-q"]
    assert main(args) == 0
    return log


def _model_rows(log: Path) -> np.ndarray:
    return read_model(log)


def test_the_live_model_s_rows_are_the_replay_s_to_the_bit(live_log: Path) -> None:
    rows = _model_rows(live_log)
    config = replay_config(None, str(live_log))
    pipeline = Pipeline(config)
    pushes = _Pushes()
    pipeline.estimator.log = pushes  # type: ignore[attr-defined]  # the real Estimator
    source = open_log(str(live_log))
    try:
        for _ in run_steps(pipeline, source.batches(65536)):
            pass
    finally:
        source.close()
    blocks, lagged = _stream(config, [_whole(pushes.pushes)], round(LAG_S / 0.02))
    assert len(rows) == len(blocks) > 250  # 6 s of 20 ms blocks
    assert np.array_equal(rows["block"], np.arange(len(rows)))
    assert rows["board_t"].tobytes() == blocks.t.tobytes()
    grad, sig = gradient_permil(
        blocks.x_filt[:, state.S], blocks.p_filt[:, state.S, state.S], config.g
    )
    assert rows["gradient"].tobytes() == grad.tobytes()
    assert rows["gradient_sigma"].tobytes() == sig.tobytes()
    assert rows["gradient_lagged"].tobytes() == lagged.gradient.tobytes()
    assert rows["wheel_error"].tobytes() == blocks.x_filt[:, state.E].tobytes()
    assert rows["bias"].tobytes() == blocks.x_filt[:, list(state.BIASES)].tobytes()
    assert np.all(rows["lag_s"] == LAG_S)
    # and it is the track's: the lagged gradient near 12 permil once the filter settled
    late = rows[len(rows) // 2 :]
    assert np.all(np.abs(late["gradient_lagged"] - 12.0) < 4.0 * late["gradient_lagged_sigma"])
    assert math.isfinite(float(late["compliance_sigma"][-1]))


def test_the_model_topic_reads_in_mcap_core(live_log: Path) -> None:
    js: McapJs = install()
    report = js.check(live_log)
    model = [c for c in report["channels"] if c["topic"] == S.MODEL_TOPIC]
    assert len(model) == 1
    assert (model[0]["schemaName"], model[0]["schemaEncoding"]) == (
        "acb3.bench.Model",
        "jsonschema",
    )
    assert model[0]["count"] == len(_model_rows(live_log))  # index, stream, statistics agree
    first = model[0]["first"]["value"]
    assert first["block"] == 0 and first["lag_s"] == LAG_S and "b3_sigma" in first


def test_a_run_without_the_model_logs_no_model_topic(tmp_path: Path) -> None:
    (tmp_path / "s.toml").write_text(SCENARIO.replace("duration_s = 6.0", "duration_s = 1.0"))
    log = tmp_path / "run.mcap"
    assert main(["run", "--emulate", str(tmp_path / "s.toml"), "--mcap", str(log), "-q"]) == 0
    assert len(_model_rows(log)) == 0
    assert S.MODEL_TOPIC not in _topics(log)


def _topics(log: Path) -> set[str]:
    from mcap.reader import make_reader

    with log.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {c.topic for c in summary.channels.values()}


def test_a_full_queue_drops_the_push_counted_and_never_waits() -> None:
    config = replay_config(None, None)
    model = LiveModel(config, 0.0, max_samples=5)
    n = 8  # more than the queue holds: dropped at once
    model.add(np.arange(n) * 0.005, np.zeros((n, 3)), np.full(n, 7), None)
    model.add(np.arange(4) * 0.005, np.zeros((4, 3)), np.full(4, 7), None)
    view = model.view()
    assert (view.dropped_pushes, view.dropped_samples) == (1, 8)
    model.close()
    assert model.error is None
    assert model.blocks == 1  # the four samples kept: one block, smoothed at the end
    rows = model.take_rows()
    assert len(rows) == 1 and math.isfinite(rows["gradient_lagged"][0])


def test_a_stalled_model_never_holds_up_the_pushes_it_drops() -> None:
    config = replay_config(None, None)
    model = LiveModel(config, 0.0, max_samples=100)
    go = threading.Event()
    stream_push = model._fwd.push

    def stalled(*args, **kwargs):  # type: ignore[no-untyped-def]
        go.wait()
        return stream_push(*args, **kwargs)

    model._fwd.push = stalled  # type: ignore[method-assign]
    n = 40
    for k in range(10):  # 400 samples while the model is stuck: 100 fit, the rest dropped
        b = (np.arange(n) + k * n) / config.sample_rate_hz
        model.add(b, np.zeros((n, 3)), np.full(n, 7), None)
    view = model.view()
    # the thread may take the first one or two pushes off the queue before it stalls (it
    # takes whatever waits as one): 2 to 4 pushes kept
    assert 6 <= view.dropped_pushes <= 8 and view.dropped_samples == n * view.dropped_pushes
    go.set()
    model.close()
    kept = 10 - view.dropped_pushes
    assert model.error is None and model._fwd.samples == kept * n
    assert len(model.take_rows()) == model.blocks == -(-kept * n // model.block)


def test_what_the_model_drops_is_told_in_the_log_and_the_status_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A model thread that falls behind (each of its steps held 0.3 s) with room for 20
    samples: the pushes it cannot hold are dropped, and every dropped sample is in the
    log's MODEL_DROPPED events and the run's closing status line (never silently)."""
    import re
    import time

    from bench.fusion.model.stream import ForwardStream
    from bench.mcaplog.recorded import read_events
    from bench.records.events import EventKind

    push = ForwardStream.push

    def slow(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        time.sleep(0.3)
        return push(self, *args, **kwargs)

    monkeypatch.setattr("bench.live.model.QUEUE_SAMPLES", 20)
    monkeypatch.setattr(ForwardStream, "push", slow)
    (tmp_path / "s.toml").write_text(SCENARIO.replace("duration_s = 6.0", "duration_s = 1.5"))
    log = tmp_path / "run.mcap"
    args = ["run", "--emulate", str(tmp_path / "s.toml"), "--mcap", str(log), "--lag", "0.2"]
    assert main(args) == 0
    shown = re.findall(r"mdrop (\d+)", capsys.readouterr().err)
    assert shown, "the closing status line names the model's drops"
    told = [e for e in read_events(log) if e["kind"] == EventKind.MODEL_DROPPED]
    assert told and all(e["level"] == 3 for e in told)  # WARNING
    assert sum(int(e["value"]) for e in told) == int(shown[-1]) > 0
    assert "samples dropped by the live model's full queue" in told[0]["message"]
