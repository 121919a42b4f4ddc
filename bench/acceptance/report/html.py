"""report.html: a self-contained page with the verdicts, the plots and the run's record."""

from __future__ import annotations

import html
from typing import Any

from bench import __version__
from bench.acceptance.checks.base import ESTIMATORS
from bench.acceptance.checks.registry import KINDS
from bench.acceptance.expectation import expectation_text, status_of
from bench.acceptance.outcome import RunOutcome
from bench.acceptance.report.measured import measured_text
from bench.acceptance.report.text import format_limits, format_margin, window_text
from bench.acceptance.signoff import SIGN_OFF_CSS, dut_html, sign_off_html

_CSS = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1150px;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;
vertical-align:top;text-align:left;font-size:90%}th{background:#f3f3f3}
.pass{background:#d9f2d9}.warn{background:#fff2cc}.fail{background:#f8d0d0}
.error{background:#e0c0f0}.skip{background:#eee}.banner{font-size:150%;padding:.5em 1em;
display:inline-block;border-radius:4px}pre{background:#f7f7f7;padding:1em;overflow:auto;
font-size:85%}img{max-width:100%;border:1px solid #ddd;margin:.5em 0}
"""


def report_html(outcome: RunOutcome, record: dict[str, Any], plots: dict[str, str]) -> str:
    e = html.escape
    plan = outcome.plan
    c = record["counts"]
    rows = []
    for m in outcome.measurements:
        status = status_of(m)
        note = "" if m.expect is None and status == "ok" else f"<br>{e(expectation_text(m))}"
        rows.append(
            f"<tr class='{m.verdict}'><td>{e(m.name)}</td><td>{e(m.kind)}</td>"
            f"<td>{e(', '.join(plan.requirement_ids(m.name)))}</td>"
            f"<td>{e(measured_text(m))}</td><td>{e(format_limits(m))}</td>"
            f"<td>{e(format_margin(m))}</td>"
            f"<td>{e(window_text(m))}</td><td><b>{m.verdict.upper()}</b>{note}</td>"
            f"<td>{e(m.detail)}</td></tr>"
        )
    run = record["run"]
    info = [
        ("plan", f"{plan.name}: {plan.title}"),
        ("expected verdict", plan.expect),
        ("mode", outcome.mode),
        ("source", outcome.source),
        ("started (UTC)", outcome.started_utc),
        ("finished (UTC)", outcome.finished_utc),
        ("wall time", f"{outcome.wall_s:.2f} s"),
        ("bench version", __version__),
        ("calibration", outcome.config.announcement().removeprefix("calibration: ")),
    ]
    if "frames" in run:
        info.append(("frames sent / received / logged", _frames_text(run["frames"])))
        info.append(("samples", str(run["samples"])))
    faults = "".join(
        f"<tr><td>#{f['index']}</td><td>{e(f['label'])}</td><td>{f['onset_sample']}</td>"
        f"<td>{f['affected']}</td></tr>"
        for f in run.get("faults", [])
    )
    steps = "".join(
        f"<tr><td>{s['step']}</td><td>{e(s['prompt'])}</td><td>{s['expected_permil']:g}</td>"
        f"<td>{e(s['answer'])}</td><td>{s['window_s'][0]:.2f}-{s['window_s'][1]:.2f} s</td></tr>"
        for s in run.get("steps", [])
    )
    imgs = "".join(
        f"<h3>{e(name)}</h3><img src='{e(fn)}' alt='{e(name)} plot'>" for name, fn in plots.items()
    )
    est = ", ".join(f"{k} = {v[0]}" for k, v in ESTIMATORS.items())
    kinds = ", ".join(KINDS)
    parts = [
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
        f"<title>acceptance {e(plan.name)}: {outcome.result.upper()}</title>",
        f"<style>{_CSS}{SIGN_OFF_CSS}</style></head><body>",
        f"<h1>Acceptance run: {e(plan.name)}</h1><p>{e(plan.title)}</p>",
        f"<div class='banner {outcome.result}'>{outcome.result.upper()}</div>",
        f"<p><b>{e(record['summary'])}</b>; the device's verdict: "
        f"{outcome.verdict.upper()}, the plan expects {e(plan.expect)}.</p>",
        f"<p>{c['pass']} pass, {c['warn']} warn, {c['fail']} fail, {c['error']} error, "
        f"{c['skip']} skipped.</p>",
    ]
    if outcome.error:
        parts.append(f"<p class='error'><b>The bench failed:</b> {e(outcome.error)}</p>")
    parts += [
        dut_html(outcome.context),
        "<h2>Run</h2><table>",
        *(f"<tr><th>{e(k)}</th><td>{e(v)}</td></tr>" for k, v in info),
        "</table><h2>Checks</h2><table><tr><th>check</th><th>kind</th><th>requirement</th>"
        "<th>measured</th>",
        "<th>limits</th><th>margin</th><th>window</th><th>verdict</th><th>detail</th></tr>",
        *rows,
        "</table>",
    ]
    if faults:
        parts.append(
            "<h2>Injected faults</h2><table><tr><th>#</th><th>fault</th>"
            f"<th>onset sample</th><th>frames affected</th></tr>{faults}</table>"
        )
    if steps:
        parts.append(
            "<h2>Operator steps</h2><table><tr><th>step</th><th>prompt</th>"
            f"<th>expected, permil</th><th>answer</th><th>window</th></tr>{steps}</table>"
        )
    parts += [
        f"<h2>Plots</h2>{imgs or '<p>no samples: nothing to plot</p>'}",
        f"<h2>Plan</h2><pre>{e(plan.text)}</pre>",
        f"<h2>Calibration config</h2><p>{e(outcome.config.describe())}</p>"
        f"<pre>{e(outcome.config.to_toml())}</pre>",
        sign_off_html(),
        f"<p><small>Check kinds: {e(kinds)}. Estimator columns: {e(est)}. "
        "Full record: <a href='record.json'>record.json</a>; CI: "
        "<a href='junit.xml'>junit.xml</a>; the run: run.mcap "
        "(<code>bench replay run.mcap</code>).</small></p></body></html>",
    ]
    return "\n".join(parts)


def _frames_text(frames: dict[str, Any]) -> str:
    return " / ".join(
        "-" if frames[k] is None else str(frames[k]) for k in ("sent", "received", "logged")
    )
