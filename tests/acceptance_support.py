"""What the acceptance tests share: the JUnit schema check, a level-grade scenario and
running ``bench accept`` on a plan text."""

from __future__ import annotations

import functools
import re
import xml.etree.ElementTree as ET
from pathlib import Path

from lxml import etree

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

SCHEMAS = Path(__file__).parent / "schemas"
JUNIT_SCHEMAS = ("junit-10.xsd", "junit-4.xsd")
"""Jenkins' xUnit plugin schema and the dtkit junit-4.xsd (whose elements GitLab parses)."""


@functools.cache
def junit_schema(name: str) -> etree.XMLSchema:
    return etree.XMLSchema(etree.parse(str(SCHEMAS / name)))


def schema_errors(path: Path, name: str) -> list[str]:
    """What the XSD ``name`` finds wrong with the XML file at ``path`` (empty: valid)."""
    schema = junit_schema(name)
    if schema.validate(etree.parse(str(path))):
        return []
    return [f"{e.line}: {e.message}" for e in schema.error_log]


def validate_junit(path: Path) -> ET.Element:
    """junit.xml valid under both shipped XSDs (lxml), and its counts true to its cases."""
    for name in JUNIT_SCHEMAS:
        assert schema_errors(path, name) == [], name
    root = ET.parse(path).getroot()
    for suite in root.iter("testsuite"):
        assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d", suite.get("timestamp", ""))
        cases = suite.findall("testcase")
        kids = [c.tag for case in cases for c in case]
        assert all(c.get("classname") and float(c.get("time", "x")) >= 0 for c in cases)
        assert int(suite.get("tests", "-1")) == len(cases)
        assert int(suite.get("failures", "-1")) == kids.count("failure")
        assert int(suite.get("errors", "-1")) == kids.count("error")
        assert int(suite.get("skipped", "-1")) == kids.count("skipped")
    return root
