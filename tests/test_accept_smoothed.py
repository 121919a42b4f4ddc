"""`bench accept` with checks on the smoothed gradient (``estimator = "smoothed"``, issue 26).

Expectations are the emulator's configured truth and a hand computation: the board has a
bias of DELTA * cos(theta_i) on each channel i, which a sensor along the track of DELTA
m/s^2 would read: the gravity along the track itself. Its calibration sheet as built
knows it (the offsets take it out) and the plan passes; the same sheet with its offsets
zeroed does not, and every estimator then reads S + DELTA for S: the gradient off by
1000 DELTA / g = 1.02 permil (at the run's 12 permil, 1000 DELTA g^2 / (g^2 - S^2)^1.5).
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from tests.test_replay_smooth import (
    GRADIENT,
    SCENARIO,
    WHEEL,
    channels_toml,
    emulate_run,
    uncalibrated,
)

ANGLES = (30.0, 0.0, -30.0)
DELTA = 0.01  # m/s^2 along the track
G = 9.80665
S = G * math.sin(math.atan(GRADIENT / 1000.0))
OFF_PERMIL = 1000.0 * DELTA * G * G / (G * G - S * S) ** 1.5  # 1.0199

PLAN = """
scenario = "run.toml"

[plan]
title = "the smoothed gradient on a 12 permil grade"
expect = "pass"

[[checks]]
name = "smoothed gradient bias"
kind = "gradient_error"
estimator = "smoothed"
statistic = "bias"
max_permil = 0.3
[[checks]]
name = "smoothed gradient availability"
kind = "availability"
estimator = "smoothed"
min_fraction = 0.8
[[checks]]
name = "smoothed sigma coverage"
kind = "sigma_coverage"
estimator = "smoothed"
min_fraction = 0.9
[[checks]]
name = "bench estimator availability"
kind = "availability"
estimator = "signed"
min_fraction = 0.5
"""


@pytest.fixture(scope="module")
def plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("accept_smoothed")
    bias = [DELTA * math.cos(math.radians(a)) for a in ANGLES]
    emulate_run(d, SCENARIO + channels_toml(ANGLES, bias))  # and d/cal.toml as built
    (d / "smoothed.toml").write_text(PLAN)
    uncalibrated(d)
    return d


def _record(out: Path) -> dict[str, dict]:  # type: ignore[type-arg]
    record = json.loads((out / "record.json").read_text())
    return {m["name"]: m for m in record["measurements"]}


def _junit(out: Path) -> dict[str, list[str]]:
    cases = ET.parse(out / "junit.xml").getroot().iter("testcase")
    return {c.get("name", ""): [e.tag for e in c] for c in cases}


def test_the_board_as_built_passes_its_smoothed_checks(plan: Path) -> None:
    out = plan / "built"
    args = ["accept", str(plan / "smoothed.toml"), "--out", str(out), "--no-plots"]
    assert main(args) == 0
    got = _record(out)
    bias = got["smoothed gradient bias"]
    assert bias["verdict"] == "pass" and bias["value"] < 0.1, bias["detail"]
    assert bias["extra"]["column"] == "gradient_smoothed"
    assert got["smoothed gradient availability"]["verdict"] == "pass"
    assert got["smoothed sigma coverage"]["verdict"] == "pass"
    assert "failure" not in _junit(out)["smoothed gradient bias"]
    # the record keeps the run's estimates: the emulated wheel reads 2 % high
    wheel = json.loads((out / "record.json").read_text())["run"]["smoother"]
    e = wheel["wheel_diameter_error_smoothed"]
    assert abs(e["median"] - WHEEL) <= 2.0 * e["sigma"] and e["unit"] == "1"


def test_a_bias_the_calibration_does_not_know_fails_by_the_hand_computed_error(
    plan: Path,
) -> None:
    out = plan / "zeroed"
    args = ["accept", str(plan / "smoothed.toml"), "--out", str(out), "--no-plots"]
    assert main([*args, "--config", str(plan / "cal0.toml")]) == 1
    got = _record(out)
    bias = got["smoothed gradient bias"]
    assert bias["verdict"] == "fail"
    assert abs(bias["value"] - OFF_PERMIL) < 0.15, (bias["value"], OFF_PERMIL)
    # the smoother's sigma does not know the calibration is off: its coverage fails too
    assert got["smoothed sigma coverage"]["verdict"] == "fail"
    junit = _junit(out)
    assert "failure" in junit["smoothed gradient bias"]
    assert "failure" not in junit["smoothed gradient availability"]


def test_a_smoothed_check_on_filtered_results_is_skipped_with_its_reason() -> None:
    from bench.acceptance.checks.base import CheckSpec
    from bench.acceptance.checks.registry import run_check
    from bench.acceptance.model import RunData
    from bench.records.events import EVENT_DTYPE
    from bench.records.results import RESULT_DTYPE

    spec = CheckSpec(1, "s", "gradient_error", {"estimator": "smoothed", "max_permil": 1.0})
    run = RunData(np.zeros(3, RESULT_DTYPE), np.zeros(0, EVENT_DTYPE), 100.0, 0, np.zeros(3))
    m = run_check(spec, run)
    assert m.verdict == "skip" and "gradient_smoothed" in m.detail


def test_the_smoothed_columns_join_the_run_s_results_by_sample_counter() -> None:
    """A sample the log lacks (a frame the recording lost) gets none; order is not assumed."""
    from bench.acceptance.smoothing import join_by_counter
    from bench.records.results import RESULT_DTYPE
    from bench.replay.model_columns import MODEL_DTYPE

    results = np.zeros(4, RESULT_DTYPE)
    results["n"] = [10, 11, 12, 13]
    results["gradient_signed"] = [1.0, 2.0, 3.0, 4.0]
    logged = np.zeros(3, MODEL_DTYPE)
    logged["n"] = [13, 10, 12]  # 11 is not in the log
    logged["gradient_smoothed"] = [40.0, 10.0, 30.0]
    logged["model_e"] = [0.4, 0.1, 0.3]
    out = join_by_counter(results, logged)
    assert out["gradient_signed"].tolist() == [1.0, 2.0, 3.0, 4.0]  # the run's own, untouched
    got = out["gradient_smoothed"]
    assert got[0] == 10.0 and math.isnan(got[1]) and got[2] == 30.0 and got[3] == 40.0
    assert out["model_e"][3] == 0.4


def test_a_realtime_run_is_smoothed_from_its_recording(plan: Path) -> None:
    """The live path (LiveRunner on the virtual bus): the smoother reads run.mcap after the
    run and its gradient is joined to the live results by counter, as in an emulated run."""
    out = plan / "realtime"
    args = ["accept", str(plan / "smoothed.toml"), "--out", str(out), "--no-plots"]
    assert main([*args, "--realtime", "--speed", "10"]) == 0
    got = _record(out)
    assert got["smoothed gradient bias"]["value"] < 0.1
    assert got["smoothed gradient availability"]["value"] > 0.95
