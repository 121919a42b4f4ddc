"""Faults at start-up of a live run: a log path that cannot be used, a scenario by name.

``bench run`` either runs and finishes its log, or says in one ``bench: error:`` line why
not and exits 2 -- no traceback, no half-open bus left behind.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers import bench

ROOT = Path(__file__).resolve().parent.parent


def test_log_folder_that_is_a_file(tmp_path: Path) -> None:
    blocker = tmp_path / "logs"
    blocker.write_text("a file where the log folder should be")
    scenario = ROOT / "devices" / "scenarios" / "demo.toml"
    proc = bench(
        "run",
        "--emulate",
        str(scenario),
        "--mcap",
        str(blocker / "run.mcap"),
        "--duration",
        "1",
        "-q",
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bench: error:") and "logs" in lines[0]


@pytest.mark.parametrize("name", ["demo", "demo.toml"])
def test_builtin_scenario_by_name_runs_and_logs(tmp_path: Path, name: str) -> None:
    """`bench run --emulate demo`: load_scenario resolves built-in names, so recording
    (which attaches the scenario file) must use the resolved path too."""
    mcap = tmp_path / "run.mcap"
    proc = bench("run", "--emulate", name, "--mcap", str(mcap), "--duration", "1", "-q")
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.returncode == 0, proc.stderr
    from bench.mcaplog.reader import McapLog

    with McapLog(mcap) as log:
        assert log.complete
        assert log.attachment("demo.toml") is not None  # the scenario travels with the log
