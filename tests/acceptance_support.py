"""What the acceptance tests share: the JUnit schema check, a level-grade scenario and
running ``bench accept`` on a plan text."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

from bench.cli import main

LEVEL_GRADE = """[[scenario.track]]
length_m = 1000.0
gradient_permil = 20.0
[[scenario.channels]]
noise_mps2 = 2e-5
[[scenario.channels]]
noise_mps2 = 2e-5
[[scenario.channels]]
noise_mps2 = 2e-5
"""
"""A plan's scenario tail: 1 km at 20 permil, three quiet channels (ICD noise class)."""


def accept(tmp_path: Path, name: str, text: str, *extra: str) -> tuple[int, Path]:
    """``bench accept NAME.toml --out DIR --no-plots EXTRA...``: the exit code and DIR."""
    plan = tmp_path / f"{name}.toml"
    plan.write_text(text)
    out = tmp_path / "out"
    return main(["accept", str(plan), "--out", str(out), "--no-plots", *extra]), out


# --------------------------------------------------------------------------- JUnit schema

_SUITE_CHILDREN = {"properties", "testcase", "system-out", "system-err"}
_CASE_CHILDREN = {"properties", "skipped", "error", "failure", "system-out", "system-err"}


def _number(value: str | None, kind: type) -> None:
    assert value is not None
    kind(value)  # raises on a malformed count or time


def validate_junit(path: Path) -> ET.Element:
    """The JUnit XML schema CI servers read (Jenkins junit-10.xsd, as GitLab and GitHub
    accept it), checked rule by rule: elements, required attributes, types, counts."""
    root = ET.parse(path).getroot()
    assert root.tag == "testsuites"
    suites = list(root)
    assert suites and all(s.tag == "testsuite" for s in suites)
    for suite in suites:
        assert suite.get("name")
        for attr in ("tests", "failures", "errors", "skipped"):
            _number(suite.get(attr), int)
        _number(suite.get("time"), float)
        assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d", suite.get("timestamp", ""))
        tags = [c.tag for c in suite]
        assert set(tags) <= _SUITE_CHILDREN
        assert tags.count("properties") <= 1 and tags[0] == "properties"
        for prop in suite.iter("property"):
            assert prop.get("name") is not None and prop.get("value") is not None
        cases = suite.findall("testcase")
        counted = {"failure": 0, "error": 0, "skipped": 0}
        for case in cases:
            assert case.get("name") and case.get("classname")
            _number(case.get("time"), float)
            kids = [c.tag for c in case]
            assert set(kids) <= _CASE_CHILDREN
            assert "properties" not in kids[1:]  # at most one, first (pytest, Xray, Testmo)
            assert sum(k in ("failure", "error", "skipped") for k in kids) <= 1
            for k in counted:
                counted[k] += kids.count(k)
        assert int(suite.get("tests", "-1")) == len(cases)
        assert int(suite.get("failures", "-1")) == counted["failure"]
        assert int(suite.get("errors", "-1")) == counted["error"]
        assert int(suite.get("skipped", "-1")) == counted["skipped"]
    return root
