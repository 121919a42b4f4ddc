"""junit.xml validates against the schemas CI servers read (issue 28): Jenkins' junit-10.xsd
and junit-4.xsd (whose elements GitLab parses), both shipped in tests/schemas/ and checked
with lxml; requirement IDs sit where those readers show them; one unit convention for a
check's margin in the console, junit.xml and report.html."""

from __future__ import annotations

import dataclasses
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bench.acceptance.model import Measurement
from bench.acceptance.plan import load_plan
from bench.acceptance.report.junit import junit_xml
from bench.acceptance.runner import Options, run_plan
from bench.acceptance.units import quantity
from tests.acceptance_support import JUNIT_SCHEMAS, LEVEL_GRADE, accept, schema_errors

PLAN = (
    """
[plan]
title = "one check of each outcome"
expect = "pass"

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
name = "available, with a warning"
kind = "availability"
estimator = "signed"
min_fraction = 0.5
warn_fraction = 1.0
requirement = ["REQ-AV-1", "REQ-AV-2"]
[[checks]]
name = "device held to a micro-permil"
kind = "gradient_error"
from_s = 1.0
max_permil = 0.000001
"""
)
"""pass, warn and fail in one real run."""


@pytest.fixture(scope="module")
def accepted(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, Path]:
    tmp = tmp_path_factory.mktemp("junit")
    return accept(tmp, "outcomes", PLAN)


@pytest.mark.parametrize("schema", JUNIT_SCHEMAS)
def test_a_real_accept_junit_validates(accepted: tuple[int, Path], schema: str) -> None:
    code, out = accepted
    assert code == 1  # the device's check fails
    root = ET.parse(out / "junit.xml").getroot()
    verdicts = [
        re.search(r"verdict: (\w+)", c.findtext("system-out") or "").group(1)  # type: ignore[union-attr]
        for c in root.iter("testcase")
    ]
    assert verdicts == ["PASS", "WARN", "FAIL"]
    assert len(root.findall(".//failure")) == 1
    assert schema_errors(out / "junit.xml", schema) == []


def test_requirement_ids_where_jenkins_and_gitlab_show_them(accepted: tuple[int, Path]) -> None:
    _, out = accepted
    root = ET.parse(out / "junit.xml").getroot()
    props = {p.get("name"): p.get("value") for p in root.iter("property")}
    assert props["requirements.estimator on the grade"] == "REQ-GRD-012"
    assert props["requirements.available, with a warning"] == "REQ-AV-1, REQ-AV-2"
    assert "requirements.device held to a micro-permil" not in props
    first = [(c.findtext("system-out") or "").splitlines()[0] for c in root.iter("testcase")]
    assert first == ["requirements: REQ-GRD-012", "requirements: REQ-AV-1, REQ-AV-2",
                     "requirements: none"]  # fmt: skip


@pytest.mark.parametrize("schema", JUNIT_SCHEMAS)
def test_every_outcome_validates(tmp_path: Path, accepted: tuple[int, Path], schema: str) -> None:
    """The outcomes a short run does not produce (error, skip, a check meant to fail that
    did not) in one file beside the others, under each schema."""
    outcome = run_plan(load_plan("link-can"), Options(out_dir=tmp_path / "run", command="pytest"))
    made = [
        Measurement("passes", "k", 1.0, "permil", {"max": 2.0}, "pass", "ok", margin=1.0),
        Measurement("fails", "k", 3.0, "permil", {"max": 2.0}, "fail", "over", margin=-1.0),
        Measurement("errs", "k", None, "permil", {"max": 2.0}, "error", "no data"),
        Measurement("skipped", "k", None, "permil", {"max": 2.0}, "skip", "operator: s"),
        Measurement("meant to fail", "k", 1.0, "permil", {"max": 2.0}, "pass", "", expect="fail"),
    ]
    path = tmp_path / "junit.xml"
    path.write_bytes(junit_xml(dataclasses.replace(outcome, measurements=made)))
    assert schema_errors(path, schema) == []
    root = ET.parse(path).getroot()
    suite = root.find("testsuite")
    assert suite is not None
    assert (suite.get("failures"), suite.get("errors"), suite.get("skipped")) == ("2", "1", "1")
    assert root.findtext(".//testcase[@name='skipped']/skipped") == "operator: s"


@pytest.mark.parametrize("schema", JUNIT_SCHEMAS)
def test_the_schemas_reject_what_the_bench_used_to_write(tmp_path: Path, schema: str) -> None:
    """The shipped XSDs are not a rubber stamp: the old file's two faults are caught."""
    old = tmp_path / "old.xml"
    old.write_text(
        '<testsuites name="a" tests="1" failures="0" errors="0" skipped="0">'
        '<testsuite name="a" tests="1" failures="0" errors="0">'
        '<testcase name="c" classname="a"><properties>'
        '<property name="requirement" value="REQ-1"/></properties></testcase>'
        "</testsuite></testsuites>"
    )
    errors = " ".join(schema_errors(old, schema))
    assert "'skipped' is not allowed" in errors
    fixed = tmp_path / "fixed.xml"
    fixed.write_text(old.read_text().replace(' skipped="0"', "", 1))
    assert "properties" in " ".join(schema_errors(fixed, schema))


def test_one_unit_for_a_margin_in_console_junit_and_html(accepted: tuple[int, Path]) -> None:
    """A fraction's margin reads "N %" in all three, never "0.x fraction" or a bare number
    (the console prints each warning's detail line, which junit.xml carries as "detail:")."""
    _, out = accepted
    root = ET.parse(out / "junit.xml").getroot()
    text = root.findtext(".//testcase[@name='available, with a warning']/system-out") or ""
    margin = re.search(r"^margin: (.*)$", text, re.M).group(1)  # type: ignore[union-attr]
    measured = float(re.search(r"^measured: ([\d.]+) %$", text, re.M).group(1))  # type: ignore[union-attr]
    # the margin to the 50 % fail limit, in percent: measured - 50 (6 significant digits)
    assert margin.endswith(" %") and float(margin[:-2]) == pytest.approx(measured - 50, abs=1e-3)
    assert "fraction" not in (out / "junit.xml").read_text()
    detail = re.search(r"^detail: (.*)$", text, re.M).group(1)  # type: ignore[union-attr]
    assert re.search(r"\(margin [\d.]+ %\)", detail) and "warning limit 100 %" in detail
    html = (out / "report.html").read_text()
    assert f"<td>{margin}</td>" in html
    permil = root.findtext(".//testcase[@name='estimator on the grade']/system-out") or ""
    assert re.search(r"^margin: [\d.e-]+ permil$", permil, re.M)


def test_quantity_reads_a_fraction_as_percent() -> None:
    assert quantity(0.169167, "fraction") == "16.9167 %"
    assert quantity(0.5, "fraction") == "50 %"
    assert quantity(0.00093754, "permil", digits=4) == "0.0009375 permil"
    assert quantity(float("nan"), "permil") == quantity(None, "s") == "n/a"
