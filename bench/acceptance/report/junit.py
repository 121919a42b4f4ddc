"""junit.xml: one testcase per check, for CI systems."""

from __future__ import annotations

import re
import socket
import xml.etree.ElementTree as ET

from bench import __version__
from bench.acceptance.expectation import expectation_text, plan_line, status_of
from bench.acceptance.outcome import RunOutcome
from bench.acceptance.report.measured import measured_text
from bench.acceptance.report.text import format_limits, format_margin, window_text


def junit_xml(outcome: RunOutcome) -> bytes:
    """JUnit XML that validates against the schemas CI servers read (Jenkins' junit-10.xsd
    and junit-4.xsd, whose elements GitLab parses; tests/schemas/): a testsuite per plan, a
    testcase per check; a failure -> <failure> (a check meant to fail that failed is none:
    it behaved as designed; one meant to fail that did not is a failure), error -> <error>,
    skip -> <skipped>. Requirement IDs go where those readers show them, since neither schema
    allows <properties> in a testcase: the first line of the testcase's <system-out> (which
    GitLab and Jenkins show with the case), and one suite property per traced check,
    ``requirements.<check>``. The case's name stays the check's name, so a CI server's
    history of a check survives a change of its requirement IDs."""
    ms = outcome.measurements
    statuses = [status_of(m) for m in ms]
    suite_name = f"acceptance.{outcome.plan.name}"
    attrs = {
        "name": suite_name,
        "tests": str(len(ms)),
        "failures": str(sum(s in ("failure", "not as designed") for s in statuses)),
        "errors": str(statuses.count("error")),
        "time": f"{outcome.wall_s:.3f}",
    }
    root = ET.Element("testsuites", attrs)  # neither schema has "skipped" up here
    suite = ET.SubElement(
        root,
        "testsuite",
        {
            **attrs,
            "skipped": str(statuses.count("skipped")),
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
        *(
            (f"requirements.{m.name}", ", ".join(ids))
            for m in ms
            if (ids := outcome.plan.requirement_ids(m.name))
        ),
    ):
        ET.SubElement(props, "property", {"name": name, "value": value})
    for m, status in zip(ms, statuses, strict=True):
        case = ET.SubElement(
            suite, "testcase", {"classname": suite_name, "name": m.name, "time": "0.000"}
        )
        requirements = outcome.plan.requirement_ids(m.name)
        expectation = expectation_text(m)
        text = (
            f"requirements: {', '.join(requirements) or 'none'}\n"
            f"verdict: {m.verdict.upper()}\n"
            f"expectation: {expectation}\n"
            f"kind: {m.kind}\n"
            f"measured: {measured_text(m)}\n"
            f"limits: {format_limits(m)}\n"
            f"margin: {format_margin(m)}\n"
            f"window: {window_text(m)}\n"
            f"detail: {m.detail}\n"
        )
        if status == "failure":
            ET.SubElement(case, "failure", {"message": m.detail[:500], "type": "limit"}).text = text
        elif status == "not as designed":
            message = f"{expectation}: {m.detail}"[:500]
            ET.SubElement(case, "failure", {"message": message, "type": "expectation"}).text = text
        elif status == "error":
            ET.SubElement(case, "error", {"message": m.detail[:500], "type": "bench"}).text = text
        elif status == "skipped":
            # junit-4.xsd's <skipped> is text only; Jenkins and GitLab read the text
            ET.SubElement(case, "skipped").text = m.detail[:500]
        ET.SubElement(case, "system-out").text = text
    out = ET.SubElement(suite, "system-out")
    out.text = plan_line(outcome.plan.name, outcome.plan.expect, ms, outcome.result) + (
        f" ({outcome.error})" if outcome.error else ""
    )
    ET.SubElement(suite, "system-err").text = outcome.error or ""
    _xml_text_only(root)
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


_NOT_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ud800-\udfff\ufffe\uffff]")
"""Characters XML 1.0 cannot carry, escaped or not: ElementTree writes them as they are
and the file is not well-formed (an error text naming a file, a host name)."""


def _xml_text_only(root: ET.Element) -> None:
    """Every text and attribute with those characters written as ``\\xNN`` instead."""

    def clean(text: str | None) -> str | None:
        if text is None or not _NOT_XML.search(text):
            return text
        return _NOT_XML.sub(lambda m: f"\\x{ord(m.group()):02x}", text)

    for el in root.iter():
        el.text, el.tail = clean(el.text), clean(el.tail)
        for key, value in el.attrib.items():
            el.attrib[key] = clean(value) or ""
