"""Wrong or missing records, and runs that ended early (issue 27).

SIGTERM in `bench accept` writes the records as Ctrl-C does; a control character never makes
junit.xml ill-formed; `--compare` of a log without recorded results says so; a closed
status pipe does not end a recording; bad fleet options are one line; a Foxglove port in
use is not reported as an MCAP failure; a `--no-plots` report into a reused folder keeps
no plots of an earlier run.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bench.cli import main
from tests.test_hostile_paths import ROOT, one_error

PLAN = (
    '[plan]\ntitle = "records"\nexpect = "pass"\n[scenario]\nduration_s = {d}\n'
    '[[checks]]\nkind = "no_frame_loss"\n'
)


def bench(*argv: str, **kw) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "bench", *argv],
        cwd=kw.pop("cwd"),
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        **kw,
    )


def _wait_for(path: Path, proc: subprocess.Popen[str], limit_s: float = 120.0) -> None:
    """Until ``path`` exists (a hang guard, not a speed bound)."""
    deadline = time.monotonic() + limit_s
    while not path.exists():
        assert proc.poll() is None, "the command ended before it started the run"
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.05)


# -- SIGTERM in bench accept ---------------------------------------------------------------
def test_sigterm_during_a_realtime_acceptance_writes_the_records(tmp_path):
    """Ctrl-C wrote junit.xml, record.json and report.html; SIGTERM left none."""
    plan = tmp_path / "long.toml"
    plan.write_text(PLAN.format(d=120.0))
    out = tmp_path / "acc"
    proc = bench(
        "accept", str(plan), "--realtime", "--out", str(out), "--no-plots",
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        _wait_for(out / "run.mcap", proc)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, err
    assert err.strip().splitlines()[-1] == "bench: error: stopped by SIGTERM"
    record = json.loads((out / "record.json").read_text())
    assert record["verdict"] == "error" and record["error"] == "stopped by SIGTERM"
    suite = ET.parse(out / "junit.xml").getroot().find("testsuite")
    assert suite is not None and suite.get("errors") == "1"
    assert (out / "report.html").stat().st_size > 0
    assert main(["log", "info", str(out / "run.mcap")]) == 0  # a finished recording


# -- control characters and junit.xml --------------------------------------------------------
@pytest.mark.parametrize(
    ("argv", "env"),
    [
        (["--station", "bench\x07room"], {}),
        (["--operator", "ann\x1bx"], {}),
        (["--dut-serial", "SN\x00-1"], {}),
        ([], {"BENCH_STATION": "lab\x01"}),
    ],
    ids=["station", "operator", "serial", "env-station"],
)
def test_a_control_character_for_the_record_is_refused(tmp_path, capsys, monkeypatch, argv, env):
    """`--station` with a control character made junit.xml not well-formed."""
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN.format(d=1.0))
    out = tmp_path / "acc"
    line = one_error(main(["accept", str(plan), "--out", str(out), *argv]), capsys.readouterr().err)
    assert "control character U+00" in line
    assert not out.exists()


def test_junit_escapes_control_characters_it_is_handed(tmp_path, capsys):
    """What no option check sees (here a scenario file's name, which reaches the record
    as the source) is escaped: junit.xml parses and shows the character as \\x07."""
    sc = tmp_path / "board\x07.toml"
    sc.write_text("duration_s = 2.0\nseed = 2\n")
    plan = tmp_path / "live.toml"
    plan.write_text(
        '[plan]\ntitle = "live"\nexpect = "pass"\nduration_s = 1.0\n'
        '[[checks]]\nkind = "no_frame_loss"\n'
    )
    out = tmp_path / "acc"
    code = main(["accept", str(plan), "--emulate", str(sc), "--out", str(out), "--no-plots"])
    assert code == 0, capsys.readouterr().err
    props = {p.get("name"): p.get("value") for p in ET.parse(out / "junit.xml").iter("property")}
    assert props["source"] == "virtual board board\\x07.toml"


# -- --compare on a log without results --------------------------------------------------------
def test_compare_of_a_log_without_recorded_results_is_an_error(tmp_path, capsys):
    """It said "DIFFERENT (0 of 0 rows differ)", exit 1."""
    sc = tmp_path / "s.toml"
    sc.write_text("duration_s = 1.0\nseed = 2\n")
    log = tmp_path / "emu.mcap"
    assert main(["emulate", str(sc), "--out", str(log), "-q"]) == 0
    capsys.readouterr()
    line = one_error(main(["replay", str(log), "--compare", "-q"]), capsys.readouterr().err)
    assert "no recorded results" in line and "without --compare" in line


# -- a closed status pipe ----------------------------------------------------------------------
def test_a_closed_status_pipe_does_not_end_the_recording(tmp_path):
    """`bench run ... 2>&1 | head -1` stopped after 0.2 s of 4, exit 0."""
    sc = tmp_path / "long.toml"
    sc.write_text("duration_s = 60.0\nseed = 2\n")
    log = tmp_path / "run.mcap"
    proc = bench(
        "run", "--emulate", str(sc), "--duration", "4", "--mcap", str(log), "--status-every",
        "0.1", cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        proc.stdout.readline()  # what `head -1` reads, then it is gone
        proc.stdout.close()
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0
    from bench.mcaplog.info import log_info

    info = log_info(log)
    assert info["complete"] and info["duration_s"] >= 3.0, info["duration_s"]


# -- bench fleet's options ---------------------------------------------------------------------
@pytest.mark.parametrize(
    ("option", "expect"),
    [
        (["--scheduler", "garbage"], "not a scheduler address"),
        (["--scheduler", "tcp://127.0.0.1:port"], "not a scheduler address"),
        (["--workers", "100000"], "per CPU"),
        (["--workers", "0"], ">= 1"),
    ],
)
def test_bad_fleet_options_are_one_line(tmp_path, capsys, option, expect):
    """--scheduler garbage printed a ValueError traceback; --workers 100000 grew memory."""
    log = tmp_path / "x.log"
    log.write_text("(1.000000) can0 101#0000000000000000\n")
    line = one_error(
        main(["fleet", str(log), "--out", str(tmp_path / "f"), *option]),
        capsys.readouterr().err,
    )
    assert expect in line


# -- a Foxglove port in use --------------------------------------------------------------------
@pytest.mark.parametrize("log", ["--no-log", "--mcap"])
def test_a_foxglove_port_in_use_is_not_an_mcap_failure(tmp_path, log):
    """A port in use printed "MCAP log FAILED: ws:/..." even with --no-log."""
    sc = tmp_path / "s.toml"
    sc.write_text("duration_s = 1.0\nseed = 2\n")
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    port = str(taken.getsockname()[1])
    argv = ["run", "--emulate", str(sc), "--foxglove", port, "--duration", "1"]
    argv += ["--no-log"] if log == "--no-log" else ["--mcap", str(tmp_path / "run.mcap")]
    try:
        proc = bench(*argv, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        _, err = proc.communicate(timeout=120)
    finally:
        taken.close()
    assert proc.returncode == 2, err
    assert err.strip().splitlines()[-1].startswith("bench: error: --foxglove: ")
    assert "FAILED" not in err and "Traceback" not in err
    if log == "--no-log":  # nothing of a log but (when it comes first) the warning of none
        mcap_lines = {line for line in err.splitlines() if "MCAP" in line}
        assert mcap_lines <= {"bench: WARNING: --no-log: this run leaves no MCAP record"}, err


# -- --no-plots into a reused folder -----------------------------------------------------------
def test_a_report_without_plots_keeps_no_plots_of_an_earlier_run(tmp_path, capsys):
    plan = tmp_path / "p.toml"
    plan.write_text(PLAN.format(d=2.0))
    out = tmp_path / "acc"
    assert main(["accept", str(plan), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.glob("*.png"))  # the first run drew its plots
    assert main(["accept", str(plan), "--out", str(out), "--no-plots"]) == 0
    capsys.readouterr()
    assert not list(out.glob("*.png"))
    assert "png" not in (out / "report.html").read_text()
    assert not [k for k in json.loads((out / "record.json").read_text())["files"] if ".png" in k]
