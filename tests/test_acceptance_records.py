"""Acceptance records a reviewer can sign (issue 18): the device under test, station,
operator, the board as it reported, a sign-off block and requirement IDs in junit.xml,
record.json and report.html; a plan meant to fail that fails as designed exits 0, one whose
check does not fail as designed exits 1; a step check shows the reading beside its error."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bench.cli import main
from tests.acceptance_support import LEVEL_GRADE, accept, validate_junit

PLAN = (
    """
[plan]
title = "level, traced to requirements"
expect = "pass"
dut = { serial = "SN-0042", firmware = "1.2.3" }

[scenario]
seed = 5
duration_s = 3.0
sample_rate_hz = 200
initial_speed_mps = 10.0
body_modes.enabled = false  # the plan's 0.5 permil predates the body modes (issue 25)
"""
    + LEVEL_GRADE
    + """
[[checks]]
name = "estimator on the grade"
kind = "gradient_error"
estimator = "signed"
from_s = 1.0
max_permil = 0.5
requirement = "REQ-GRD-012"
[[checks]]
name = "nothing lost"
kind = "no_frame_loss"
requirement = ["REQ-LNK-001", "REQ-LNK-002"]
[[checks]]
name = "untraced"
kind = "no_frame_loss"
"""
)


def run(tmp_path: Path, text: str, *extra: str) -> tuple[int, Path]:
    return accept(tmp_path, "traced", text, *extra)


def props(element: ET.Element | None) -> list[tuple[str, str]]:
    assert element is not None
    return [(p.get("name", ""), p.get("value", "")) for p in element.iter("property")]


def test_record_junit_and_report_carry_dut_station_operator_board_and_requirements(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out = run(tmp_path, PLAN, "--operator", "A. Tester", "--station", "bench-3")
    assert code == 0
    record = json.loads((out / "record.json").read_text())
    assert record["dut"]["serial"] == "SN-0042" and record["dut"]["firmware"] == "1.2.3"
    board = record["dut"]["board"]
    # the virtual board's BOARD_STATUS: base id 0x100 (ICD default), RUN, at the scenario rate
    assert board["base_id"] == "0x100" and board["state"] == "RUN"
    assert board["sample_rate_hz"] == 200 and board["status_frames"] >= 25  # 10 Hz for 3 s
    assert record["station"] == "bench-3" and record["operator"] == "A. Tester"
    assert [s["role"] for s in record["sign_off"]] == ["tested by", "reviewed by", "approved by"]
    assert all(s["name"] is None and s["signature"] is None for s in record["sign_off"])
    reqs = {m["name"]: m["requirements"] for m in record["measurements"]}
    assert reqs == {
        "estimator on the grade": ["REQ-GRD-012"],
        "nothing lost": ["REQ-LNK-001", "REQ-LNK-002"],
        "untraced": [],
    }
    root = validate_junit(out / "junit.xml")
    suite = dict(props(root.find("testsuite/properties")))
    assert suite["dut_serial"] == "SN-0042" and suite["dut_firmware"] == "1.2.3"
    assert suite["station"] == "bench-3" and suite["operator"] == "A. Tester"
    assert suite["dut_board_base_id"] == "0x100"
    # requirement IDs where Jenkins and GitLab show them: the case's system-out, first line,
    # and the suite's properties (neither schema has <properties> in a testcase)
    assert suite["requirements.nothing lost"] == "REQ-LNK-001, REQ-LNK-002"
    assert suite["requirements.estimator on the grade"] == "REQ-GRD-012"
    assert "requirements.untraced" not in suite
    out_text = root.findtext(".//testcase[@name='nothing lost']/system-out") or ""
    assert out_text.splitlines()[0] == "requirements: REQ-LNK-001, REQ-LNK-002"
    assert (root.findtext(".//testcase[@name='untraced']/system-out") or "").startswith(
        "requirements: none\n"
    )
    html = (out / "report.html").read_text()
    for text in ("SN-0042", "1.2.3", "bench-3", "A. Tester", "REQ-GRD-012", "REQ-LNK-002"):
        assert text in html
    assert "Sign-off" in html and html.count("class='blank'") == 9  # 3 roles x 3 fields
    assert "base id 0x100, RUN, 200 Hz" in html


def test_command_line_names_the_unit_over_the_plan(tmp_path: Path) -> None:
    code, out = run(tmp_path, PLAN, "--dut-serial", "SN-0099", "--dut-firmware", "2.0.0")
    assert code == 0
    record = json.loads((out / "record.json").read_text())
    assert (record["dut"]["serial"], record["dut"]["firmware"]) == ("SN-0099", "2.0.0")


def test_no_dut_given_says_so(tmp_path: Path) -> None:
    code, out = run(tmp_path, PLAN.replace('dut = { serial = "SN-0042", firmware = "1.2.3" }', ""))
    assert code == 0
    record = json.loads((out / "record.json").read_text())
    assert record["dut"]["serial"] is None
    assert "serial number</th><td>not given" in (out / "report.html").read_text()


def test_plan_meant_to_fail_that_fails_as_designed_exits_0_without_a_junit_failure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main(["accept", "reference-sign", "--out", str(out), "--no-plots"]) == 0
    printed = " ".join(capsys.readouterr().out.split())
    assert "PASS plan reference-sign (behaved as designed" in printed
    root = validate_junit(out / "junit.xml")
    assert root.findall(".//failure") == [] and root.find("testsuite").get("failures") == "0"
    case = root.find(".//testcase[@name='device gradient with its sign']")
    text = case.find("system-out").text  # type: ignore[union-attr]
    assert "verdict: FAIL" in text and "behaved as designed: expected to FAIL" in text
    record = json.loads((out / "record.json").read_text())
    assert record["verdict"] == "fail"  # what the device did
    assert record["result"] == "pass" and record["exit_code"] == 0  # what the plan meant


def test_a_check_that_does_not_fail_as_designed_is_a_failure(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from bench.acceptance.plan import resolve_plan_path

    text = resolve_plan_path("reference-sign").read_text()
    # held to the magnitude instead of the sign, the device now passes the check meant to fail
    loosened = text.replace('truth = "signed"\nfrom_s = 1.0', 'truth = "magnitude"\nfrom_s = 1.0')
    assert loosened != text
    code, out = run(tmp_path, loosened)
    assert code == 1
    printed = " ".join(capsys.readouterr().out.split())
    assert "did not fail as expected" in printed
    root = validate_junit(out / "junit.xml")
    failure = root.find(".//testcase[@name='device gradient with its sign']/failure")
    assert failure is not None and failure.get("type") == "expectation"
    assert "expected to FAIL" in (failure.get("message") or "")
    assert json.loads((out / "record.json").read_text())["result"] == "fail"


def test_tilt_table_step_shows_the_reading_and_its_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("COLUMNS", "200")  # the content, not the layout, is tested here
    out = tmp_path / "out"
    assert main(["accept", "tilt-table", "--out", str(out), "--no-plots"]) == 0
    printed = capsys.readouterr().out
    line = next(ln for ln in printed.splitlines() if "+10 permil (mean)" in ln)
    reading, error = re.search(r"([-\d.]+) permil \(error ([\d.e-]+) permil\)", line).groups()
    assert abs(float(reading) - 10.0) < 0.3  # the device reads the table's +10 permil
    assert float(error) == pytest.approx(abs(float(reading) - 10.0), abs=1e-5)
    record = json.loads((out / "record.json").read_text())
    m = next(m for m in record["measurements"] if m["name"].endswith("+10 permil (mean)"))
    assert m["reading"] == pytest.approx(float(reading), rel=1e-5)
    assert m["value"] == pytest.approx(abs(m["reading"] - 10.0))
    assert f"{float(reading):.6g} permil (error" in (out / "report.html").read_text()
