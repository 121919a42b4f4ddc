"""Every output file of an acceptance run into its folder: run.mcap's digest, the plots,
junit.xml, record.json and report.html."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bench.acceptance.outcome import RunOutcome
from bench.acceptance.report.html import report_html
from bench.acceptance.report.junit import junit_xml
from bench.acceptance.report.plots import write_plots
from bench.acceptance.report.record import build_record, sha256_of


def write_reports(outcome: RunOutcome, *, plots: bool = True) -> dict[str, Path]:
    """Write every output file into the outcome's folder; return their paths (also kept
    in outcome.files). A plot that cannot be drawn is an error of the bench, recorded."""
    out = outcome.out_dir
    mcap = out / "run.mcap"
    files: dict[str, Any] = {}
    if mcap.exists():
        outcome.files["mcap"] = mcap
        files["run.mcap"] = {"bytes": mcap.stat().st_size, "sha256": sha256_of(mcap)}
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
