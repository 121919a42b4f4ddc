"""`bench calibrate` end to end: emulated log -> calibrated config -> acceptance plan, and the
one-line errors an operator sees for bad input."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.config import Config, load_config
from devices.emulator import scenario_from_dict, simulate
from devices.writers import write_candump
from tests.test_calibration_fit import AS_BUILT, IN_MOTION, TABLE, TILT_STEPS, TOLERANCE_DEG

# A plan for this board as built (its scenario), judged on the bench's estimator: its limit
# is what a calibrated bench must meet and an uncalibrated one does not.
PLAN = """
[plan]
title = "board built up to 0.5 deg off nominal, in motion over grades"
expect = "pass"

[scenario]
seed = 9
duration_s = 50.0
vertical_curve_m = 100.0
vertical_curve_accel = true
[[scenario.track]]
length_m = 100.0
gradient_permil = 5.0
[[scenario.track]]
length_m = 300.0
gradient_permil = -12.0
[[scenario.track]]
length_m = 3000.0
gradient_permil = 20.0
[[scenario.train]]
duration_s = 15.0
accel_mps2 = 0.8
[[scenario.train]]
duration_s = 20.0
[[scenario.train]]
duration_s = 15.0
accel_mps2 = -0.3
[scenario.body_pitch]
enabled = false  # the body's pitch would read as gradient: the limits are of before it
{channels}
{checks}
"""
WINDOWS = ((2.0, 15.0), (17.0, 35.0), (37.0, 50.0))  # a_ref settles for 2 s after a step
CHECK = """
[[checks]]
name = "bench estimator {lo:g}-{hi:g} s (rms error)"
kind = "gradient_error"
estimator = "signed"
statistic = "rms"
from_s = {lo}
to_s = {hi}
max_permil = 0.3
"""


def plan_text() -> str:
    chans = "".join(
        f"[[scenario.channels]]\nangle_deg = {a}\nnoise_mps2 = 0.002\n" for a in AS_BUILT
    )
    checks = "".join(CHECK.format(lo=lo, hi=hi) for lo, hi in WINDOWS)
    return PLAN.replace("{channels}", chans).replace("{checks}", checks)


def write_log(scenario: dict, path: Path) -> Path:
    write_candump(path, simulate(scenario_from_dict(scenario)).frames)
    return path


def test_calibrated_config_passes_the_plan_the_nominal_config_fails(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = write_log(IN_MOTION, tmp_path / "run.log")
    out = tmp_path / "cal.toml"
    assert main(["calibrate", str(log), "--out", str(out)]) == 0
    report = capsys.readouterr().out
    assert "against SPEED_REF (in motion)" in report and "+/-" in report and "residual" in report
    cal = load_config(out)
    angles = np.array([c.angle_deg for c in cal.channels])
    assert np.all(np.abs(angles - np.array(AS_BUILT)) <= TOLERANCE_DEG)
    assert cal.estimator == Config().estimator and cal.g == Config().g

    plan = tmp_path / "as-built.toml"
    plan.write_text(plan_text(), encoding="utf-8")
    nominal = tmp_path / "nominal.toml"
    nominal.write_text(Config().to_toml(), encoding="utf-8")
    assert (
        main(
            [
                "accept",
                str(plan),
                "--config",
                str(nominal),
                "--out",
                str(tmp_path / "a"),
                "--no-plots",
            ]
        )
        == 1
    )
    assert capsys.readouterr().out.count("FAIL bench estimator") == len(WINDOWS)
    assert (
        main(
            ["accept", str(plan), "--config", str(out), "--out", str(tmp_path / "b"), "--no-plots"]
        )
        == 0
    )


def test_table_reference_from_a_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = write_log(TILT_STEPS, tmp_path / "table.log")
    table = tmp_path / "steps.csv"
    rows = "\n".join(f"{a:g},{b:g},{g:g}" for a, b, g in TABLE)
    table.write_text("start_s,end_s,gradient_permil\n# settled steps\n" + rows + "\n")
    out = tmp_path / "cal.toml"
    assert main(["calibrate", str(log), "--reference", str(table), "--out", str(out)]) == 0
    assert "tilt-table steps (4)" in capsys.readouterr().out
    data = tomllib.loads(out.read_text())
    angles = np.array([c["angle_deg"] for c in data["channels"]])
    assert np.all(np.abs(angles - np.array(AS_BUILT)) <= TOLERANCE_DEG)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["missing.log"], "log file not found"),
        (["{log}", "--reference", "gps"], "--reference 'gps': expected speed, level or a .csv"),
        (["{log}", "--reference", "nope.csv"], "table file not found"),
        (["{log}", "--reference", "{bad_csv}"], "bad.csv:2: expected numbers"),
        (["{log}", "--reference", "{backwards_csv}"], "end_s 1 must be after start_s 5"),
        (["{log}", "--reference", "speed"], "no SPEED_REF in the recording"),
        (["{log}", "--config", "nope.toml"], "cannot read config"),
    ],
)
def test_operator_mistakes_are_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    log = write_log({"duration_s": 2.0, "speed_ref": False}, tmp_path / "still.log")
    (tmp_path / "bad.csv").write_text("start_s,end_s,gradient_permil\n1,two,3\n")
    (tmp_path / "backwards.csv").write_text("5,1,0\n")
    names = {
        "log": log,
        "bad_csv": tmp_path / "bad.csv",
        "backwards_csv": tmp_path / "backwards.csv",
    }
    argv = ["calibrate", *(a.format(**names) for a in args), "--out", str(tmp_path / "o.toml")]
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(tmp_path)
        assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench: error: ") and err.count("\n") == 1
    assert message in err
    assert not (tmp_path / "o.toml").exists()
