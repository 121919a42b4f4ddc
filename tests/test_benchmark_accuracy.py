"""The accuracy benchmark's scoring (benchmarks/accuracy.py) on hand-made error series, and its
place in the benchmark harness."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks import __main__ as harness
from benchmarks.accuracy import SCENARIOS, Run, figures_for, scores
from devices.emulator import builtin_scenarios, load_scenario


def test_scores_count_every_sampling_instant_and_sign_only_for_the_estimator():
    truth = np.array([-10.0, -10.0, -10.0, -10.0, 5.0, 5.0, 5.0, 5.0, 5.0, 5.0])
    n = np.arange(8)  # the last two instants never produced a result row
    value = np.array([-10.5, -9.0, np.nan, -10.0, 5.2, 7.0, np.nan, 5.0])
    sigma = np.array([0.5, 0.2, 1.0, 0.1, 0.15, 2.0, 1.0, 0.1])
    s = scores(value, n, truth, sigma, signed=True)
    err = np.array([0.5, 1.0, 0.0, 0.2, 2.0, 0.0])
    assert s["rms"] == pytest.approx(math.sqrt((err**2).mean()))
    assert s["max"] == pytest.approx(2.0)
    assert s["avail"] == pytest.approx(60.0)  # 6 of 10 instants
    assert s["wrong"] == pytest.approx(10.0)  # only the 2.0 error is > 1 (1.0 is not)
    # within 2 sigma: 0.5<=1, 1.0>0.4, 0<=0.2, 0.2<=0.3, 2.0<=4, 0<=0.2 -> 5 of 6
    assert s["cover"] == pytest.approx(100 * 5 / 6)
    ref = scores(np.abs(value), n, truth, None, signed=False)  # against |truth|
    assert ref["avail"] == pytest.approx(60.0) and ref["cover"] is None
    assert ref["max"] == pytest.approx(2.0)
    assert scores(np.full(3, np.nan), np.arange(3), np.zeros(3), None, True)["rms"] is None


def test_targets_apply_to_the_estimator_only_and_relax_without_a_usable_odometer():
    truth = np.zeros(100)
    run = Run("metro_run", "d", truth, np.arange(100), np.full(100, 2.0), np.full(100, 0.1), None)
    figs = {f.key: f for f in figures_for(run)}
    assert figs["accuracy_metro_run_estimator_rms"].status == "PASS"
    assert figs["accuracy_metro_run_reference_rms"].status == "INFO"
    assert "accuracy_metro_run_estimator_cover" not in figs  # no gradient_sigma column
    slide = {f.key: f for f in figures_for(Run("wheel_slide", "d", *list(vars(run).values())[2:]))}
    assert slide["accuracy_wheel_slide_estimator_rms"].target is None
    assert slide["accuracy_wheel_slide_estimator_wrong"].target == 0.5


def test_every_listed_scenario_is_shipped_and_realistic():
    names = set(builtin_scenarios())
    for name in SCENARIOS:
        assert name in names
        sc = load_scenario(name)
        assert sc.sample_rate_hz == 200 and sc.duration_s <= 600
        assert all(c.noise_mps2 > 0 for c in sc.channels)
    assert load_scenario("metro_vibration").vibration.vertical_mps2 == 0.25
    assert load_scenario("wheel_slide").odometer.slide_depth_mps == 0.9
    assert load_scenario("metro_run").jerk_mps3 == 0.8


def test_accuracy_is_part_of_the_full_run_and_a_partial_run_keeps_other_figures(
    tmp_path: Path,
):
    assert "accuracy" in {p[0] for p in harness.PLAN}
    old = {
        "started": "then",
        "machine": {"cpu": "old"},
        "runs": [{"name": "fusion"}, {"name": "accuracy"}],
        "figures": [
            {"key": "fusion_core", "label": "f", "value": 1.0, "unit": "x"},
            {"key": "accuracy_metro_run_estimator_rms", "label": "a", "value": 9.0, "unit": "x"},
        ],
    }
    path = tmp_path / "r.json"
    path.write_text(json.dumps(old))
    figures, runs = harness._kept(path, {"accuracy"})
    assert [f.key for f in figures] == ["fusion_core"]
    assert runs == [{"name": "fusion", "started": "then", "machine": {"cpu": "old"}}]
    assert harness._measurement_of({"key": "live_max_rate_strict"}) == "live_rate"
    assert harness._measurement_of({"key": "replay_mcap"}) == "replay"
    assert harness._measurement_of({"key": "latency_p99_tui"}) == "latency"


def test_the_curves_told_are_the_shipped_lines_curves_and_their_bound_holds():
    """metro_vibration's line: grade changes at 250, 750, 1150 and 1600 m (0/+30/0/-25/+5
    permil), each over an 80 m vertical curve centred on it: k = g sin(atan(0.03)) / 80 m
    = 3.68e-3 (m/s^2)/m for a 30 permil change. Told each start and end, the filter gives
    at least what it gives with its own curve detector, and nothing confidently wrong."""
    from benchmarks.accuracy import curve_changes, emulate, replay_run, replay_told

    sim, config = emulate("metro_vibration")
    changes = curve_changes(sim.truth, config.g)
    assert len(changes) == 8
    where = np.interp([t for t, _ in changes], sim.truth["time_s"], sim.truth["position_m"])
    np.testing.assert_allclose(where, [210, 290, 710, 790, 1110, 1190, 1560, 1640], atol=1.0)
    k30 = config.g * math.sin(math.atan(0.03)) / 80.0
    steps = [dk for _, dk in changes]
    np.testing.assert_allclose(steps[:4], [k30, -k30, -k30, k30], atol=1e-4)
    told = scores(*_est(replay_told("metro_vibration")))
    own = scores(*_est(replay_run("metro_vibration")))
    assert told["avail"] >= own["avail"] and told["wrong"] <= 0.05


def _est(run: Run) -> tuple:
    return run.estimator, run.n, run.truth_permil, run.sigma, True
