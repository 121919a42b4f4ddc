"""What an acceptance run leaves in DIR: junit.xml, record.json, report.html and its PNGs.

junit.xml is for CI (one testcase per check; measured value and limits in its
system-out); record.json is the review record (every measurement with limits, units,
verdict, timestamps, bench version, config and plan); report.html is for people. Plots use
matplotlib's Agg canvas through Figure objects, never pyplot: no display, no global state.
"""

from __future__ import annotations

import hashlib
import html
import json
import math
import platform
import socket
import sys
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from bench import __version__
from bench.acceptance.checks import ESTIMATORS, KINDS, VERDICTS, Measurement, RunData
from bench.acceptance.expectation import expectation_text, plan_line, status_of
from bench.acceptance.measured import measured_text, reading_extra
from bench.acceptance.signoff import SIGN_OFF_CSS, dut_html, sign_off_html
from bench.events import EventKind

if TYPE_CHECKING:
    from bench.acceptance.runner import Outcome

RECORD_FORMAT = "acb3-bench-acceptance-record/1"
MAX_POINTS = 6000
"""Points per plotted line: longer series are reduced to a min/max envelope."""
PLOTS = ("gradient", "slopes", "votes", "errors")


# --------------------------------------------------------------------------- helpers


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def format_limits(m: Measurement) -> str:
    parts = []
    for key, v in m.limits.items():
        shown = f"{v:.4%}" if m.unit == "fraction" else f"{v:g} {m.unit}"
        sign = "<=" if "max" in key else ">="
        parts.append(f"{'warn ' if key.startswith('warn') else ''}{sign} {shown}")
    return ", ".join(parts)


def _window_text(m: Measurement) -> str:
    if m.from_s is None and m.to_s is None:
        return "whole run"
    return f"{m.from_s or 0:g} s to {'end' if m.to_s is None else f'{m.to_s:g} s'}"


def counts(measurements: list[Measurement]) -> dict[str, int]:
    return {v: sum(m.verdict == v for m in measurements) for v in VERDICTS}


# --------------------------------------------------------------------------- junit


def junit_xml(outcome: Outcome) -> bytes:
    """JUnit XML in the form Jenkins, GitLab and GitHub read: a testsuite per plan, a
    testcase per check; fail -> <failure>, error -> <error>, skip -> <skipped>; the
    measured value, limits and verdict in each testcase's <system-out>."""
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
            f"window: {_window_text(m)}\n"
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


# --------------------------------------------------------------------------- record


def _measurement(m: Measurement, plan: Any) -> dict[str, Any]:
    """A measurement as recorded: its own fields, how it stands against the plan's
    expectation, the requirements it verifies and a step check's reading."""
    return {
        **m.as_dict(),
        "status": status_of(m),
        "expectation": expectation_text(m),
        "requirements": list(plan.requirement_ids(m.name)),
        **reading_extra(m),
    }


def build_record(outcome: Outcome, files: dict[str, Any]) -> dict[str, Any]:
    plan = outcome.plan
    run = outcome.run
    run_info: dict[str, Any] = {
        "mode": outcome.mode,
        "source": outcome.source,
        "link": plan.link if run is None else run.link,
        "started_utc": outcome.started_utc,
        "finished_utc": outcome.finished_utc,
        "wall_s": round(outcome.wall_s, 3),
    }
    if run is not None:
        run_info.update(
            sample_rate_hz=run.rate_hz,
            samples=len(run.results),
            sample_span=run.n_samples,
            frames={
                "sent": run.frames_sent,
                "received": run.frames_received,
                "logged": run.frames_logged,
                "dropped": run.frames_dropped,
            },
            latency_ms=None if run.latency_ms is None else list(run.latency_ms),
            steps=[
                {
                    "step": s.index,
                    "prompt": s.prompt,
                    "expected_permil": s.expected_permil,
                    "answer": s.answer,
                    "note": s.note,
                    "confirmed_at_s": s.start_s,
                    "window_s": [s.from_s, s.to_s],
                }
                for s in run.steps
            ],
            faults=[
                {
                    "index": f.index,
                    "label": f.label,
                    "kind": f.kind,
                    "channels": list(f.channels),
                    "start_s": f.start_s,
                    "end_s": f.end_s,
                    "onset_sample": f.onset_k,
                    "affected": f.affected,
                }
                for f in run.faults
            ],
        )
    run_info.update(outcome.info)
    return {
        "format": RECORD_FORMAT,
        "result": outcome.result,
        "summary": plan_line(plan.name, plan.expect, outcome.measurements, outcome.result),
        "verdict": outcome.verdict,
        "exit_code": outcome.exit_code,
        "expected_verdict": plan.expect,
        "error": outcome.error,
        **outcome.context.record(),
        "counts": counts(outcome.measurements),
        "measurements": [_measurement(m, plan) for m in outcome.measurements],
        "plan": {
            "name": plan.name,
            "title": plan.title,
            "path": None if plan.path is None else str(plan.path),
            "sha256": hashlib.sha256(plan.text.encode()).hexdigest(),
            "text": plan.text,
        },
        "bench": {
            "version": __version__,
            "python": sys.version.split()[0],
            "numpy": np.__version__,
            "platform": platform.platform(),
            "host": socket.gethostname(),
        },
        "run": run_info,
        "config": {
            "source": outcome.config.source,
            "origin": outcome.config.origin,
            "described": outcome.config.describe(),
            "toml": outcome.config.to_toml(),
            "values": outcome.config.as_dict(),
        },
        "scenario": None
        if plan.scenario is None
        else {"ref": plan.scenario_ref, "toml": plan.scenario_toml()},
        "files": files,
    }


# --------------------------------------------------------------------------- plots


def _envelope(x: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple:
    """Min/max per bin: a long series keeps its spikes when reduced for plotting."""
    n = len(x)
    if n <= max_points:
        return x, y
    bins = max_points // 2
    size = math.ceil(n / bins)
    pad = bins * size - n
    xp = np.concatenate([x, np.full(pad, x[-1])]).reshape(bins, size)
    yp = np.concatenate([y, np.full(pad, np.nan)]).reshape(bins, size)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN bins are expected
        lo, hi = np.nanmin(yp, axis=1), np.nanmax(yp, axis=1)
    xs = np.repeat(xp[:, 0], 2)
    ys = np.column_stack([lo, hi]).ravel()
    return xs, ys


def _shade(ax: Any, run: RunData) -> None:
    for f in run.faults:
        ax.axvspan(f.start_s, f.end_s, color="tab:red", alpha=0.08, lw=0)
    for s in run.steps:
        if s.answer != "skip":
            ax.axvspan(s.from_s, s.to_s, color="tab:green", alpha=0.10, lw=0)


def _figure(rows: int = 1, height: float = 3.2) -> tuple[Any, Any]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, height * rows), dpi=90, layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, axes


def plot_gradient(run: RunData, path: Path) -> None:
    fig, (ax,) = _figure()
    t = run.time_s
    r = run.results
    ax.plot(*_envelope(t, r["gradient"]), color="tab:blue", lw=0.8, label="reference (device)")
    if np.isfinite(r["gradient_signed"]).any():
        ax.plot(
            *_envelope(t, r["gradient_signed"]), color="tab:orange", lw=0.8, label="signed (bench)"
        )
    if run.truth_gradient is not None:
        tt = np.arange(len(run.truth_gradient)) / run.rate_hz
        ax.plot(*_envelope(tt, run.truth_gradient), "k--", lw=1.2, label="truth", zorder=3)
        if (run.truth_gradient < 0).any():
            ax.plot(
                *_envelope(tt, np.abs(run.truth_gradient)),
                color="grey",
                lw=1.0,
                ls=":",
                label="|truth|",
                zorder=3,
            )
    for s in run.steps:
        if s.answer != "skip":
            ax.hlines(s.expected_permil, s.from_s, s.to_s, color="tab:green", lw=2)
    _shade(ax, run)
    ax.set_ylabel("gradient, permil")
    ax.set_xlabel("run time, s")
    ax.set_title("gradient vs truth (red: fault windows, green: step windows)")
    ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)
    fig.savefig(path)


def plot_slopes(run: RunData, path: Path) -> None:
    fig, (ax,) = _figure()
    t = run.time_s
    for k, (name, color) in enumerate(
        (("s1 = g12", "tab:blue"), ("s2 = g23", "tab:orange"), ("s3 = g13", "tab:green"))
    ):
        ax.plot(*_envelope(t, run.results["slopes"][:, k]), lw=0.8, color=color, label=name)
    _shade(ax, run)
    ax.set_ylabel("pair gradient, permil")
    ax.set_xlabel("run time, s")
    ax.set_title("pair values (reference method, unsigned)")
    ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)
    fig.savefig(path)


def _timeline(run: RunData, rows: list[np.ndarray], bins: int = 1500) -> tuple[np.ndarray, float]:
    """Boolean per-sample rows -> (rows, bins) fraction of samples set per time bin."""
    span = max(run.n_samples, 1)
    bins = min(bins, span)
    k = np.clip(run.k, 0, span - 1)
    idx = (k * bins) // span
    out = np.zeros((len(rows), bins))
    total = np.bincount(idx, minlength=bins).astype(float)
    for i, row in enumerate(rows):
        out[i] = np.bincount(idx, weights=row.astype(float), minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(total > 0, out / np.maximum(total, 1), np.nan)
    return out, span / run.rate_hz


def plot_votes(run: RunData, path: Path) -> None:
    r = run.results
    rows = [~r["votes"][:, 0], ~r["votes"][:, 1], ~r["votes"][:, 2], ~r["valid"], r["degraded"]]
    rows += [r["excluded"] == c for c in (1, 2, 3)]
    rows += [~r["present"][:, c] for c in range(3)]
    labels = ["v1 failed", "v2 failed", "v3 failed", "invalid", "degraded"]
    labels += [f"ch{c} excluded" for c in (1, 2, 3)] + [f"ch{c} missing" for c in (1, 2, 3)]
    grid, end_s = _timeline(run, rows)
    fig, (ax,) = _figure(height=3.6)
    cmap = _cmap()
    ax.imshow(
        grid,
        aspect="auto",
        interpolation="nearest",
        extent=(0, end_s, len(rows) - 0.5, -0.5),
        cmap=cmap,
        vmin=0,
        vmax=1,
    )
    ax.set_yticks(range(len(rows)), labels, fontsize="small")
    ax.set_xlabel("run time, s")
    ax.set_title("vote timeline (white: never, red: every sample of the bin)")
    for f in run.faults:
        ax.axvline(f.start_s, color="black", lw=0.6, ls=":")
    fig.savefig(path)


def _cmap() -> Any:
    from matplotlib.colors import LinearSegmentedColormap

    cmap = LinearSegmentedColormap.from_list("fails", ["#ffffff", "#f4a582", "#b2182b"])
    return cmap.with_extremes(bad="#dddddd")


_EVENT_ROWS = (
    "GAP",
    "CRC_ERROR",
    "STATUS_FLAG",
    "COUNTER_JUMP",
    "DUPLICATE",
    "LATE",
    "SAMPLES_LOST",
    "LINK_ERROR",
    "EXCLUDED",
)


def plot_errors(run: RunData, measurements: list[Measurement], path: Path) -> None:
    """Top: gradient error against truth (or against each step's expected value) with the
    plan's gradient limits; bottom: the bench's fault and link events over time."""
    fig, (ax, ax2) = _figure(rows=2)
    t = run.time_s
    r = run.results
    plotted = False
    if run.truth_gradient is not None:
        truth = run.truth_at()
        e_ref = r["gradient"] - np.abs(truth)
        ax.plot(*_envelope(t, e_ref), lw=0.8, color="tab:blue", label="reference - |truth|")
        if np.isfinite(r["gradient_signed"]).any():
            e_sig = r["gradient_signed"] - truth
            ax.plot(*_envelope(t, e_sig), lw=0.8, color="tab:orange", label="signed - truth")
        plotted = True
    for s in run.steps:
        if s.answer == "skip":
            continue
        sel = (t >= s.from_s) & (t < s.to_s)
        ax.plot(t[sel], r["gradient"][sel] - abs(s.expected_permil), lw=0.8, color="tab:green")
        plotted = True
    for m in measurements:
        if m.kind not in ("gradient_error", "step_gradient") or "max" not in m.limits:
            continue
        lo = 0.0 if m.from_s is None else m.from_s
        hi = run.n_samples / run.rate_hz if m.to_s is None else m.to_s
        for sign in (1, -1):
            ax.hlines(sign * m.limits["max"], lo, hi, color="tab:red", lw=1, ls="--")
    ax.axhline(0, color="black", lw=0.5)
    ax.set_ylabel("error, permil")
    title = "gradient error (dashed: limits of the gradient checks)"
    lim = _error_range(ax, measurements)
    if lim is not None:
        ax.set_ylim(-lim, lim)
        title += f"; clipped at +/-{lim:.3g}"
    ax.set_title(title)
    if plotted:
        ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)
    _shade(ax, run)
    ev = run.events
    ks = run.event_k(ev) if len(ev) else np.zeros(0, np.int64)
    for i, name in enumerate(_EVENT_ROWS):
        sel = ev["kind"] == int(EventKind[name])
        if sel.any():
            ax2.plot(ks[sel] / run.rate_hz, np.full(int(sel.sum()), i), "|", ms=8, color="tab:red")
    ax2.set_yticks(range(len(_EVENT_ROWS)), _EVENT_ROWS, fontsize="small")
    ax2.set_ylim(-0.5, len(_EVENT_ROWS) - 0.5)
    ax2.set_xlabel("run time, s")
    ax2.set_title("fault and link events")
    ax2.grid(alpha=0.3)
    fig.savefig(path)


def _error_range(ax: Any, measurements: list[Measurement]) -> float | None:
    """A y range that shows the limits and the bulk of the errors: a few transients of
    100 permil would otherwise flatten everything a 0.5 permil limit is about."""
    ys = [np.abs(line.get_ydata()) for line in ax.get_lines()]
    ys = [y[np.isfinite(y)] for y in ys if len(y)]
    values = np.concatenate(ys) if ys else np.zeros(0)
    if len(values) == 0:
        return None
    limits = [
        m.limits["max"]
        for m in measurements
        if m.kind in ("gradient_error", "step_gradient") and "max" in m.limits
    ]
    lim = max(2.0 * float(np.percentile(values, 99.5)), 2.0 * max(limits, default=0.0), 0.05)
    return lim if lim < float(values.max()) else None


def write_plots(outcome: Outcome, out: Path) -> dict[str, str]:
    run = outcome.run
    if run is None or len(run.results) == 0:
        return {}
    jobs: dict[str, Callable[[Path], None]] = {
        "gradient": lambda p: plot_gradient(run, p),
        "slopes": lambda p: plot_slopes(run, p),
        "votes": lambda p: plot_votes(run, p),
        "errors": lambda p: plot_errors(run, outcome.measurements, p),
    }
    files = {}
    for name, job in jobs.items():
        p = out / f"{name}.png"
        job(p)
        files[name] = p.name
    return files


# --------------------------------------------------------------------------- html

_CSS = """
body{font-family:system-ui,sans-serif;margin:2em;max-width:1150px;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;
vertical-align:top;text-align:left;font-size:90%}th{background:#f3f3f3}
.pass{background:#d9f2d9}.warn{background:#fff2cc}.fail{background:#f8d0d0}
.error{background:#e0c0f0}.skip{background:#eee}.banner{font-size:150%;padding:.5em 1em;
display:inline-block;border-radius:4px}pre{background:#f7f7f7;padding:1em;overflow:auto;
font-size:85%}img{max-width:100%;border:1px solid #ddd;margin:.5em 0}
"""


def report_html(outcome: Outcome, record: dict[str, Any], plots: dict[str, str]) -> str:
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
            f"<td>{'' if m.margin is None else e(f'{m.margin:.4g}')}</td>"
            f"<td>{e(_window_text(m))}</td><td><b>{m.verdict.upper()}</b>{note}</td>"
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


# --------------------------------------------------------------------------- all of it


def write_reports(outcome: Outcome, *, plots: bool = True) -> dict[str, Path]:
    """Write every output file into the outcome's folder; return their paths (also kept
    in outcome.files). A plot that cannot be drawn is an error of the bench, recorded."""
    out = outcome.out_dir
    mcap = out / "run.mcap"
    files: dict[str, Any] = {}
    if mcap.exists():
        outcome.files["mcap"] = mcap
        files["run.mcap"] = {"bytes": mcap.stat().st_size, "sha256": _sha256(mcap)}
    if (out / "scenario.toml").exists():
        files["scenario.toml"] = {"bytes": (out / "scenario.toml").stat().st_size}
    plot_files: dict[str, str] = {}
    if plots:
        try:
            plot_files = write_plots(outcome, out)
        except Exception as exc:  # a report without plots is still a record
            outcome.info["plot_error"] = repr(exc)
    for name, fn in plot_files.items():
        outcome.files[name] = out / fn
        files[fn] = {"bytes": (out / fn).stat().st_size}
    files.update({"junit": "junit.xml", "record": "record.json", "report": "report.html"})
    record = build_record(outcome, files)
    paths = {
        "junit": out / "junit.xml",
        "record": out / "record.json",
        "report": out / "report.html",
    }
    paths["junit"].write_bytes(junit_xml(outcome))
    paths["record"].write_text(json.dumps(record, indent=2, allow_nan=False) + "\n", "utf-8")
    paths["report"].write_text(report_html(outcome, record, plot_files), "utf-8")
    outcome.files.update(paths)
    return dict(outcome.files)
