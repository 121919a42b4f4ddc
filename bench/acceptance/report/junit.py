"""junit.xml: one testcase per check, for CI systems."""

from __future__ import annotations

import socket
import xml.etree.ElementTree as ET

from bench import __version__
from bench.acceptance.outcome import RunOutcome
from bench.acceptance.report.text import counts, format_limits, format_value, window_text


def junit_xml(outcome: RunOutcome) -> bytes:
    """JUnit XML in the form Jenkins, GitLab and GitHub read: a testsuite per plan, a
    testcase per check; fail -> <failure>, error -> <error>, skip -> <skipped>; the
    measured value, limits and verdict in each testcase's <system-out>."""
    ms = outcome.measurements
    c = counts(ms)
    suite_name = f"acceptance.{outcome.plan.name}"
    attrs = {
        "name": suite_name,
        "tests": str(len(ms)),
        "failures": str(c["fail"]),
        "errors": str(c["error"]),
        "skipped": str(c["skip"]),
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
        ("verdict", outcome.verdict),
        ("mode", outcome.mode),
        ("source", outcome.source),
        ("started_utc", outcome.started_utc),
        ("finished_utc", outcome.finished_utc),
    ):
        ET.SubElement(props, "property", {"name": name, "value": value})
    for m in ms:
        case = ET.SubElement(
            suite, "testcase", {"classname": suite_name, "name": m.name, "time": "0.000"}
        )
        text = (
            f"verdict: {m.verdict.upper()}\n"
            f"kind: {m.kind}\n"
            f"measured: {format_value(m)}\n"
            f"limits: {format_limits(m)}\n"
            f"margin: {'n/a' if m.margin is None else f'{m.margin:.6g} {m.unit}'}\n"
            f"window: {window_text(m)}\n"
            f"detail: {m.detail}\n"
        )
        if m.verdict == "fail":
            ET.SubElement(case, "failure", {"message": m.detail[:500], "type": "limit"}).text = text
        elif m.verdict == "error":
            ET.SubElement(case, "error", {"message": m.detail[:500], "type": "bench"}).text = text
        elif m.verdict == "skip":
            ET.SubElement(case, "skipped", {"message": m.detail[:500]})
        ET.SubElement(case, "system-out").text = text
    out = ET.SubElement(suite, "system-out")
    out.text = f"plan {outcome.plan.name}: {outcome.verdict.upper()}" + (
        f" ({outcome.error})" if outcome.error else ""
    )
    ET.SubElement(suite, "system-err").text = outcome.error or ""
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)
