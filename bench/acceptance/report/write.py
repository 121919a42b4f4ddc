"""Every output file of an acceptance run into its folder: run.mcap's digest, the plots,
junit.xml, record.json and report.html."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bench.acceptance.outcome import RunOutcome
from bench.acceptance.report.html import report_html
from bench.acceptance.report.junit import junit_xml
from bench.acceptance.report.plots import PLOT_NAMES, write_plots
from bench.acceptance.report.record import build_record, sha256_of
from devices.paths import write_file

REPORT_FILES = ("junit.xml", "record.json", "report.html")
PLOT_FILES = tuple(f"{name}.png" for name in PLOT_NAMES)


def output_files(out: Path, *, scenario: bool) -> list[Path]:
    """Every file an acceptance run may write into ``out`` (``scenario``: the plan's
    emulated board as ``scenario.toml``), for comparing with its inputs before it starts."""
    names = ["run.mcap", *REPORT_FILES, *PLOT_FILES, *(["scenario.toml"] if scenario else [])]
    return [out / name for name in names]


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
    for stale in set(PLOT_FILES) - set(plot_files.values()):  # an earlier run's, in this folder
        (out / stale).unlink(missing_ok=True)
    files.update({"junit": "junit.xml", "record": "record.json", "report": "report.html"})
    record = build_record(outcome, files)
    paths = {
        "junit": out / "junit.xml",
        "record": out / "record.json",
        "report": out / "report.html",
    }
    # each whole or not at all: a run stopped while writing leaves no half an XML file
    write_file(paths["junit"], junit_xml(outcome))
    write_file(paths["record"], json.dumps(record, indent=2, allow_nan=False) + "\n")
    write_file(paths["report"], report_html(outcome, record, plot_files))
    outcome.files.update(paths)
    return dict(outcome.files)
