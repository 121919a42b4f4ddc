"""The randomised accuracy benchmark's harness (benchmarks/random_runs.py,
benchmarks/random_accuracy.py): drawing is deterministic and inside its documented ranges,
the written scenario files replay through `bench emulate` / `bench replay` to the scores
the harness computes in memory, and the distribution summary and target counts are right
on hand-made score lists."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.csv as pacsv
import pytest

from bench.cli import main as bench_main
from benchmarks import __main__ as harness
from benchmarks.accuracy import scores
from benchmarks.random_accuracy import (
    TARGETS,
    distribution,
    merged_spans,
    score_seed,
    summarise,
    target_met,
    write_scenarios,
)
from benchmarks.random_runs import REPORT_SEEDS, TUNING_SEEDS, draw
from devices.emulator import load_scenario

SHORT_SEED = 184  # 82 s at 54 Hz: the cheapest replay among the first 400 seeds


def test_a_seed_draws_the_same_scenario_every_time_and_seeds_differ() -> None:
    a, b = draw(1000), draw(1000)
    assert a.data == b.data and a.toml() == b.toml() and a.odometer == b.odometer
    assert a.scenario == b.scenario
    assert draw(1001).data != a.data
    assert (TUNING_SEEDS.start, TUNING_SEEDS.stop, REPORT_SEEDS.start) == (1000, 1200, 5000)
    assert not set(TUNING_SEEDS) & set(REPORT_SEEDS)


def test_drawn_values_stay_inside_their_documented_ranges() -> None:
    classes = set()
    for seed in range(300):
        d = draw(seed)
        x = d.data
        classes.add(d.odometer)
        assert 50 <= x["sample_rate_hz"] <= 1000
        assert 60 <= x["duration_s"] <= 1500
        assert x["duration_s"] <= 600 or x["sample_rate_hz"] <= 200  # long runs are slow
        assert x["vertical_curve_accel"] is True
        assert all(abs(s["gradient_permil"]) <= 40 for s in x["track"])
        for c, nominal in zip(x["channels"], (30.0, 0.0, -30.0), strict=True):
            assert abs(c["angle_deg"] - nominal) <= 0.5
            assert abs(c["bias_mps2"]) <= 0.03 and abs(c["scale_error"]) <= 1e-3
            assert 1e-6 <= c["bias_walk_mps2_per_sqrt_s"] <= 3e-5
            assert 0.0 <= c["thermal_lag_s"] <= 600.0
        assert 0.0 <= x["board"]["station_cooling_k"] <= 5.0
        bp, st = x["body_pitch"], x["standstill"]
        assert 0.03 <= bp["compliance_deg_per_mps2"] <= 0.2 and "static_deg" not in bp
        assert 0.9 <= bp["frequency_hz"] <= 2.0 and 0.15 <= bp["damping_ratio"] <= 0.35
        assert 0.005 <= bp["load_step_deg"] <= 0.05
        assert 0.003 <= st["hvac_mps2"] <= 0.03 and 0.03 <= st["door_mps2"] <= 0.3
        assert max(st["hvac_hz"], st["door_hz"]) <= 0.45 * x["sample_rate_hz"]
        assert 0.0 <= st["boarding_rate_hz"] <= 2.0
        assert x["speed_ref"] == (d.odometer != "absent")
        assert 5.0 <= d.facts["top_speed_mps"] <= 45.0
        assert 0.0 <= x["odometer"]["lag_s"] <= 0.1
        assert x["vibration"]["broadband_high_hz"] <= 0.45 * x["sample_rate_hz"]
        bm = x["body_modes"]  # issue 25's ranges: bounce 1-1.5, pitch 1.5-2, bending 7-12 Hz
        for name, unit, rms, f, z in (
            ("bounce", "rms_mps2", (0.02, 0.12), (1.0, 1.5), (0.1, 0.3)),
            ("pitch", "rms_deg", (0.003, 0.02), (1.5, 2.0), (0.1, 0.3)),
            ("bending", "rms_mps2", (0.01, 0.08), (7.0, 12.0), (0.01, 0.05)),
        ):
            assert rms[0] <= bm[name][unit] <= rms[1], name
            assert f[0] <= bm[name]["frequency_hz"] <= f[1], name
            assert z[0] <= bm[name]["damping"] <= z[1], name
        assert abs(bm["lever_m"]) <= 6.0 and 0.5 <= bm["speed_exponent"] <= 1.5
        ti = x["track_irregularity"]
        assert 6.0 <= ti["frequency_hz"] <= 12.0 and 0.05 <= ti["damping"] <= 0.2
        axles = sorted(ti["axles_m"])
        assert len(axles) == 4 and 1.98 <= axles[1] - axles[0] <= 2.62  # a wheelbase, to 1 cm
        centre = (axles[3] + axles[2] - axles[1] - axles[0]) / 4  # the bogie centres +-c
        assert 5.0 - 0.01 <= centre <= 8.0 + 0.01  # (0.01: the axles are written to 1 cm)
        assert ti["track_seed"] == seed and len(ti["features"]) <= 12
        assert all(0.2 <= abs(f["amplitude_mps2"]) <= 1.5 for f in ti["features"])
        if "joint_spacing_m" in ti:
            assert 18.0 <= ti["joint_spacing_m"] <= 30.0
            assert 0.1 <= ti["joint_amplitude_mps2"] <= 0.5
        poor = (
            x["odometer"].get("slide_depth_mps", 0) > 0
            or x["odometer"].get("slip_depth_mps", 0) > 0
            or any(f["channel"] == "speed" for f in x.get("faults", []))
        )
        assert poor == (d.odometer == "poor")
        # the train (at most 2 m/s over its top speed after a nudge) stays on the track laid
        reach = sum(s["length_m"] for s in x["track"]) - x["initial_position_m"]
        assert reach > (d.facts["top_speed_mps"] + 2.0) * x["duration_s"]
    assert classes == {"usable", "poor", "absent"}


def test_written_scenarios_are_valid_and_replay_to_the_same_scores(tmp_path: Path) -> None:
    (path,) = write_scenarios([SHORT_SEED], tmp_path)
    assert load_scenario(path).with_changes(source="", path="") == draw(
        SHORT_SEED
    ).scenario.with_changes(source="", path="")
    log, cal, truth, csv = (tmp_path / n for n in ("x.log", "c.toml", "t.csv", "r.csv"))
    cal_written = tmp_path / f"random-{SHORT_SEED}-cal.toml"
    assert bench_main(["emulate", str(path), "--out", str(log), "--truth", str(truth),
                       "--calibration-out", str(cal), "--quiet"]) == 0  # fmt: skip
    assert tomllib.loads(cal.read_text()) == tomllib.loads(cal_written.read_text())
    assert bench_main(["replay", str(log), "--config", str(cal), "--csv", str(csv)]) == 0
    res = pacsv.read_csv(csv)
    tru = pacsv.read_csv(truth)
    counter0 = tru["counter"][0].as_py()
    n = res["counter"].to_numpy() - counter0
    g = tru["gradient_permil"].to_numpy()

    def col(name: str) -> np.ndarray:
        return res[name].to_numpy(zero_copy_only=False).astype(np.float64)

    est = scores(col("gradient_signed_permil"), n, g, col("gradient_sigma_permil"), True)
    ref = scores(col("gradient_permil"), n, g, None, False)
    got = score_seed(SHORT_SEED)
    assert got["scores"]["estimator"] == pytest.approx(est, nan_ok=True)
    assert got["scores"]["reference"] == pytest.approx(ref, nan_ok=True)
    assert got["samples"] == len(g)


def _run(odometer: str, **est: float | None) -> dict[str, Any]:
    scores = {"rms": 0.1, "p99": 0.5, "max": 1.0, "avail": 99.0, "wrong": 0.0, "cover": 97.0}
    scores |= est
    missed = [t.key for t in TARGETS if target_met(t, scores[t.metric], odometer) is False]
    return {
        "odometer": odometer,
        "missed": missed,
        "scores": {"estimator": scores, "reference": dict(scores)},
    }


def test_distribution_gives_median_worst_decile_and_worst_by_direction() -> None:
    values = [float(v) for v in range(1, 11)] + [None]  # 1..10 and a run with no value
    small = distribution(values, "<=")
    assert small == {"median": 5.5, "worst_decile": pytest.approx(9.1), "worst": 10.0, "runs": 10}
    large = distribution(values, ">=")
    assert large["worst_decile"] == pytest.approx(1.9) and large["worst"] == 1.0
    assert distribution([None], "<=")["median"] is None


def test_summary_counts_the_runs_meeting_each_target_by_odometer_class() -> None:
    runs = [
        _run("usable"),
        _run("usable", avail=97.0, cover=99.5),  # misses availability and coverage
        _run("poor", avail=93.0, wrong=0.3),  # 93 % is enough with a poor odometer
        _run("absent", avail=10.0, rms=None, p99=None, cover=None),  # nothing claimed
        _run("usable", rms=None, p99=None, cover=None),  # nothing given: misses
    ]
    s = summarise(runs)
    t = s["targets"]
    assert (t["avail"]["met"], t["avail"]["runs"]) == (2, 3)
    assert (t["avail_poor"]["met"], t["avail_poor"]["runs"]) == (1, 1)
    assert (t["wrong"]["met"], t["wrong_never"]["met"]) == (4, 5)
    assert (t["cover"]["met"], t["rms"]["met"]) == (3, 4)
    assert t["rms"]["need"] == math.ceil(0.95 * 5) and t["wrong_never"]["need"] == 5
    assert s["all_met"] == 2
    assert s["distribution"]["estimator"]["avail"]["worst"] == 10.0
    assert s["distribution"]["estimator"]["rms"]["runs"] == 3


def test_spans_merge_across_short_gaps() -> None:
    mask = np.zeros(30, dtype=bool)
    mask[[2, 3, 4, 7, 8, 20, 29]] = True
    assert merged_spans(mask, 2) == [(2, 9), (20, 21), (29, 30)]
    assert merged_spans(mask, 0) == [(2, 5), (7, 9), (20, 21), (29, 30)]
    assert merged_spans(np.zeros(5, dtype=bool), 3) == []


def test_random_figures_are_a_measurement_of_their_own() -> None:
    assert harness._measurement_of({"key": "random_estimator_rms"}) == "random"
    assert harness._measurement_of({"key": "accuracy_demo_estimator_rms"}) == "accuracy"
    args = harness.argparse.Namespace(random=4, seed=1000, scenarios_out=None)
    plan, selected = harness.random_plan(args, {"accuracy"})
    assert selected == {"random"}
    assert plan[0][:2] == ("random", {"n": 4, "seed": 1000})


def test_every_figure_key_names_the_plan_measurement_that_makes_it() -> None:
    """A partial run keeps the figures of the measurements it did not rerun: each key must
    map to its own PLAN entry (replay_rss_* were taken for the replay measurement's)."""
    made_by = {
        "replay_candump_csv": "replay",
        "read_mcap": "replay",
        "replay_rss_1000000": "replay_memory",
        "replay_rss_growth": "replay_memory",
        "replay_process_csv": "replay_process",
        "replay_first_step": "replay_process",
        "replay_first_row": "replay_process",
        "live_max_rate_strict": "live_rate",
        "fleet_speedup": "fleet",
    }
    plan = {name for name, *_ in harness.PLAN}
    for key, name in made_by.items():
        assert harness._measurement_of({"key": key}) == name, key
        assert name in plan, name


def test_calibration_figures_count_runs_within_and_honest() -> None:
    from benchmarks.calibration import figures as calibration_figures

    runs = [
        {"seed": 1, "odometer": "usable", "error_deg": [0.005, -0.002, 0.0],
         "sigma_deg": [0.002, 0.002, 0.004], "within": True, "honest": True},
        {"seed": 2, "odometer": "poor", "error_deg": [0.02, 0.01, -0.004],
         "sigma_deg": [0.005, 0.01, 0.01], "within": False, "honest": False},
        {"seed": 3, "odometer": "absent", "refused": "calibration: no SPEED_REF",
         "within": False, "honest": True},
    ]  # fmt: skip
    figs = {f.key: f for f in calibration_figures(runs, 1, 1.0, 2)}
    assert figs["calibration_within"].value == 1 and figs["calibration_within"].target == 3
    assert figs["calibration_honest"].value == 2 and figs["calibration_honest"].status == "MISS"
    assert figs["calibration_worst_error"].value == pytest.approx(0.02)
    assert figs["calibration_worst_ratio"].value == pytest.approx(4.0)
    assert harness._measurement_of({"key": "calibration_within"}) == "calibration"
