"""Acceptance runs end to end: the files in DIR, the CLI's exit codes and messages, the live
path (virtual board through LiveRunner) with operator steps."""

from __future__ import annotations

import argparse
import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest

from bench.acceptance.answers import Answer
from bench.acceptance.plan import load_plan, parse_plan
from bench.acceptance.runner import Options, run_plan
from bench.cli import main
from tests.acceptance_support import LEVEL_GRADE, accept, validate_junit


def png_is_a_plot(path: Path) -> None:
    from matplotlib.image import imread

    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(data) > 15_000, f"{path.name} is suspiciously small"
    img = imread(path)
    assert img.shape[0] > 200 and img.shape[1] > 600
    gray = img[..., :3].mean(axis=2)
    assert gray.std() > 0.05  # not a blank canvas
    assert np.unique(np.round(gray, 2)).size > 20  # lines, text and colours, not two tones


# --------------------------------------------------------------------------- the files


def test_outputs_junit_record_report(tmp_path: Path) -> None:
    plan = load_plan("link-can")
    outcome = run_plan(plan, Options(out_dir=tmp_path, command="pytest"))
    assert outcome.verdict == "pass" and outcome.exit_code == 0

    root = validate_junit(tmp_path / "junit.xml")
    cases = root.findall("./testsuite/testcase")
    assert [c.get("name") for c in cases] == [c.name for c in plan.checks]
    first = cases[0].findtext("system-out") or ""
    assert "measured: 0 samples" in first and "limits: <= 2 samples" in first
    props = {p.get("name"): p.get("value") for p in root.iter("property")}
    assert props["verdict"] == "pass" and props["plan"] == "link-can"

    record = json.loads((tmp_path / "record.json").read_text())
    assert record["verdict"] == "pass" and record["exit_code"] == 0
    assert record["bench"]["version"] and record["plan"]["text"] == plan.text
    assert "[[channels]]" in record["config"]["toml"]
    assert record["run"]["started_utc"] < record["run"]["finished_utc"]
    assert record["run"]["frames"]["sent"] == record["run"]["frames"]["logged"] > 10_000
    assert [f["kind"] for f in record["run"]["faults"]] == ["loss", "duplicate", "reorder", "crc"]
    for m, spec in zip(record["measurements"], plan.checks, strict=True):
        assert m["name"] == spec.name and m["verdict"] in ("pass", "warn")
        assert m["unit"] and m["limits"] and m["value"] is not None
    mcap = tmp_path / "run.mcap"
    assert record["files"]["run.mcap"]["sha256"] == hashlib.sha256(mcap.read_bytes()).hexdigest()

    html = (tmp_path / "report.html").read_text()
    assert "<title>acceptance link-can: PASS</title>" in html
    images = re.findall(r"<img src='([^']+)'", html)
    assert sorted(images) == ["errors.png", "gradient.png", "slopes.png", "votes.png"]
    for name in images:
        png_is_a_plot(tmp_path / name)


def test_bench_failure_is_verdict_error_with_a_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def boom(scenario: object) -> None:
        raise RuntimeError("emulator exploded")

    monkeypatch.setattr("devices.emulator.simulate", boom)
    outcome = run_plan(load_plan("reference-sign"), Options(out_dir=tmp_path, plots=False))
    assert outcome.verdict == "error" and outcome.exit_code == 2
    assert "emulator exploded" in (outcome.error or "")
    root = validate_junit(tmp_path / "junit.xml")
    assert len(root.findall(".//testcase/error")) == 3
    assert json.loads((tmp_path / "record.json").read_text())["verdict"] == "error"


# --------------------------------------------------------------------------- the CLI

IMPOSSIBLE = (
    """
[plan]
title = "an impossible limit"
expect = "pass"

[scenario]
duration_s = 3.0
initial_speed_mps = 10.0
"""
    + LEVEL_GRADE
    + """
[[checks]]
name = "steady gradient"
kind = "gradient_error"
from_s = 1.0
max_permil = 0.00001
[[checks]]
kind = "no_frame_loss"
"""
)


def test_cli_list(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["accept", "--list"]) == 0
    out = capsys.readouterr().out
    for name in ("level", "accel-cruise-brake", "fault-stuck", "link-uart", "tilt-table"):
        assert name in out


def test_cli_impossible_limit_fails_and_says_by_how_much(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out_dir = accept(tmp_path, "impossible", IMPOSSIBLE)
    assert code == 1
    out = " ".join(capsys.readouterr().out.split())
    assert re.search(r"FAIL steady gradient: [\d.e-]+ permil > limit 1e-05 permil \(by [\d.]+", out)
    assert "FAIL plan impossible" in out
    root = validate_junit(out_dir / "junit.xml")
    failure = root.find(".//testcase[@name='steady gradient']/failure")
    assert failure is not None and "by" in (failure.get("message") or "")


def test_cli_broken_plan_exits_2_naming_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = tmp_path / "broken.toml"
    plan.write_text(IMPOSSIBLE.replace("max_permil = 0.00001", "max_permill = 0.00001"))
    assert main(["accept", str(plan), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "bench: error: broken.toml: checks[1].max_permill: unknown key" in err
    assert not (tmp_path / "out").exists()
    assert main(["accept", "level"]) == 2
    assert "--out DIR is required" in capsys.readouterr().err


def test_cli_board_plan_without_a_board_is_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = tmp_path / "board.toml"
    plan.write_text(BOARD_PLAN)
    assert main(["accept", str(plan), "--out", str(tmp_path / "o"), "--yes"]) == 2
    assert "runs against a board" in capsys.readouterr().err


# --------------------------------------------------------------------------- live runs

BOARD_PLAN = """
[plan]
title = "two tilt-table steps"
expect = "pass"

[[steps]]
prompt = "set +10 permil"
gradient_permil = 10.0
settle_s = 0.3
measure_s = 1.0
[[steps]]
prompt = "set -10 permil"
gradient_permil = -10.0
settle_s = 0.3
measure_s = 1.0

[[checks]]
name = "device reading"
kind = "step_gradient"
max_permil = 0.3
[[checks]]
name = "pc latency"
kind = "latency"
max_ms = 5000
[[checks]]
kind = "no_frame_loss"
"""

TABLE = """
duration_s = 3.5
speed_ref = false
[standstill]
enabled = false  # a tilt table is no car: no HVAC, no doors
[[track]]
length_m = 10.0
gradient_permil = 10.0
[[channels]]
noise_mps2 = 2e-5
[[channels]]
noise_mps2 = 2e-5
[[channels]]
noise_mps2 = 2e-5
"""


def test_live_operator_steps_on_the_virtual_board(tmp_path: Path) -> None:
    """A board plan against `--emulate` (a board standing at +10 permil): the operator
    answers at the console; step 2's reference reading replaces its expected value."""
    scenario = tmp_path / "table.toml"
    scenario.write_text(TABLE)
    plan = parse_plan(BOARD_PLAN, "board.toml")
    typed = iter(["", "10.2"])  # step 1: Enter; step 2: the inclinometer reads +10.2
    prompts: list[str] = []

    def ask(prompt: str) -> str:
        prompts.append(prompt)
        return next(typed)

    args = argparse.Namespace(emulate=str(scenario))
    outcome = run_plan(
        plan, Options(out_dir=tmp_path / "out", live_args=args, ask=ask, plots=False)
    )
    assert outcome.error is None and outcome.mode == "live"
    assert "set +10 permil" in prompts[0] and "set -10 permil" in prompts[1]
    by_name = {m.name: m for m in outcome.measurements}
    assert by_name["device reading"].verdict == "pass"
    steps = by_name["device reading"].extra["steps"]
    assert [s["expected"] for s in steps] == [10.0, 10.2]
    assert all(s["samples"] > 150 for s in steps)  # about 1 s at 200 Hz each
    assert by_name["pc latency"].verdict == "pass"  # measured: this is a live run
    assert by_name["no_frame_loss #3"].verdict == "pass"
    assert outcome.verdict == "pass"
    record = json.loads((tmp_path / "out" / "record.json").read_text())
    assert [s["answer"] for s in record["run"]["steps"]] == ["ok", "ok"]


def test_operator_steps_need_someone_to_answer(tmp_path: Path) -> None:
    from bench.errors import BenchError

    scenario = tmp_path / "table.toml"
    scenario.write_text(TABLE)
    plan = parse_plan(BOARD_PLAN, "board.toml")
    args = argparse.Namespace(emulate=str(scenario))
    with pytest.raises(BenchError, match="--yes or --steps"):
        run_plan(plan, Options(out_dir=tmp_path / "o", live_args=args))
    abort = Options(out_dir=tmp_path / "a", live_args=args, answers=[Answer("abort")])
    outcome = run_plan(plan, abort)
    assert outcome.verdict == "error" and "aborted" in (outcome.error or "")


def test_realtime_rehearsal_of_the_tilt_table_plan(tmp_path: Path) -> None:
    """The shipped tilt-table plan through the in-process virtual board and LiveRunner
    (16x real time), steps answered by --yes: the live path gives the plan's verdicts."""
    plan = load_plan("tilt-table")
    opts = Options(out_dir=tmp_path, realtime=True, speed=16.0, yes=True, plots=False)
    outcome = run_plan(plan, opts)
    assert outcome.error is None and outcome.mode == "realtime"
    assert {m.name: m.verdict for m in outcome.measurements} == {
        c.name: c.expect or "pass" for c in plan.checks
    }
    assert outcome.run is not None
    # unattended: each step starts at its at_s, exactly as in the emulated run
    assert [s.start_s for s in outcome.run.steps] == [0.0, 10.0, 20.0, 30.0]
