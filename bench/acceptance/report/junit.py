"""junit.xml: one testcase per check, for CI systems."""

from __future__ import annotations

import socket
import xml.etree.ElementTree as ET

from bench import __version__
from bench.acceptance.expectation import expectation_text, plan_line, status_of
from bench.acceptance.outcome import RunOutcome
from bench.acceptance.report.measured import measured_text
from bench.acceptance.report.text import format_limits, window_text


def junit_xml(outcome: RunOutcome) -> bytes:
    """JUnit XML in the form Jenkins, GitLab and GitHub read: a testsuite per plan, a
    testcase per check; a failure -> <failure> (a check meant to fail that failed is none:
    it behaved as designed; one meant to fail that did not is a failure), error -> <error>,
    skip -> <skipped>; the measured value, limits, verdict and expectation in each
    testcase's <system-out>, its requirement IDs as the testcase's <properties>."""
    ms = outcome.measurements
    statuses = [status_of(m) for m in ms]
    suite_name = f"acceptance.{outcome.plan.name}"
    attrs = {
        "name": suite_name,
        "tests": str(len(ms)),
        "failures": str(sum(s in ("failure", "not as designed") for s in statuses)),
        "errors": str(statuses.count("error")),
        "skipped": str(statuses.count("skipped")),
        "time": f"{outcome.wall_s:.3f}",
    }
    root = ET.Element("testsuites", attrs)
    suite = ET.SubElement(
        root,
        "testsuite",
        {
            **attrs,
            "timestamp": outcome.started_utc[:19],
            "hostname": socket.gethostname() or "localhost",
        },
    )
    props = ET.SubElement(suite, "properties")
    for name, value in (
        ("bench_version", __version__),
        ("plan", outcome.plan.name),
        ("plan_title", outcome.plan.title),
        ("expected_verdict", outcome.plan.expect),
        ("result", outcome.result),
        ("verdict", outcome.verdict),
        *outcome.context.junit_properties(),
        ("calibration", outcome.config.describe()),
        ("mode", outcome.mode),
        ("source", outcome.source),
        ("started_utc", outcome.started_utc),
        ("finished_utc", outcome.finished_utc),
    ):
        ET.SubElement(props, "property", {"name": name, "value": value})
    for m, status in zip(ms, statuses, strict=True):
        case = ET.SubElement(
            suite, "testcase", {"classname": suite_name, "name": m.name, "time": "0.000"}
        )
        requirements = outcome.plan.requirement_ids(m.name)
        if requirements:
            case_props = ET.SubElement(case, "properties")
            for rid in requirements:
                ET.SubElement(case_props, "property", {"name": "requirement", "value": rid})
        expectation = expectation_text(m)
        text = (
            f"verdict: {m.verdict.upper()}\n"
            f"expectation: {expectation}\n"
            f"kind: {m.kind}\n"
            f"measured: {measured_text(m)}\n"
            f"limits: {format_limits(m)}\n"
            f"margin: {'n/a' if m.margin is None else f'{m.margin:.6g} {m.unit}'}\n"
            f"window: {window_text(m)}\n"
            f"detail: {m.detail}\n"
        )
        if requirements:
            text += f"requirements: {', '.join(requirements)}\n"
        if status == "failure":
            ET.SubElement(case, "failure", {"message": m.detail[:500], "type": "limit"}).text = text
        elif status == "not as designed":
            message = f"{expectation}: {m.detail}"[:500]
            ET.SubElement(case, "failure", {"message": message, "type": "expectation"}).text = text
        elif status == "error":
            ET.SubElement(case, "error", {"message": m.detail[:500], "type": "bench"}).text = text
        elif status == "skipped":
            ET.SubElement(case, "skipped", {"message": m.detail[:500]})
        ET.SubElement(case, "system-out").text = text
    out = ET.SubElement(suite, "system-out")
    out.text = plan_line(outcome.plan.name, outcome.plan.expect, ms, outcome.result) + (
        f" ({outcome.error})" if outcome.error else ""
    )
    ET.SubElement(suite, "system-err").text = outcome.error or ""
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)
