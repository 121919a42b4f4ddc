"""The screen process of `bench demo` / `bench tui` draws and nothing else: the run (pipeline,
fusion, MCAP writer) lives in the engine process, so the screen never imports it.

Each case runs the real command in a fresh interpreter with the App headless (Textual's
test driver instead of a terminal), waits until snapshots from the engine have been drawn,
quits with ``q`` and reports the screen process's ``sys.modules``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.fusion import reference
from bench.records.results import VOTE_SLOPES

ROOT = Path(__file__).resolve().parent.parent

SCENARIO = """
seed = 3
duration_s = 30.0
sample_rate_hz = 100
[[track]]
length_m = 1000.0
gradient_permil = 10.0
[[channels]]
[[channels]]
[[channels]]
"""

SCREEN = """
import asyncio, json, sys
from bench.tui import app as screen
drawn = []

def headless_run(self, **kwargs):
    async def drive():
        async with self.run_test(size=(120, 40)) as pilot:
            for _ in range(1200):
                if self.snapshots_received >= 3:
                    break
                await pilot.pause(0.05)
            await pilot.press("q")
            for _ in range(1200):
                if not self.is_running:
                    break
                await pilot.pause(0.05)
    asyncio.run(drive())
    drawn.append(self.snapshots_received)
    return self.return_code

screen.BenchApp.run = headless_run
from bench.cli import main
code = main(sys.argv[1:])
modules = sorted(m for m in sys.modules if m.startswith("bench"))
print(json.dumps({"code": code, "drawn": drawn, "modules": modules}))
"""

NEVER_IN_THE_SCREEN = (
    "bench.fusion",
    "bench.pipeline.steps",
    "bench.pipeline.assembly",
    "bench.live.runner",
    "bench.mcaplog.sink",
    "bench.mcaplog.writer_process",
    "bench.engine.child",
)


def screen_process(argv: list[str]) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    proc = subprocess.run(
        [sys.executable, "-c", SCREEN, *argv],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["code"] == 0, proc.stderr[-3000:]
    return report


@pytest.mark.parametrize("command", ["demo", "tui"])
def test_screen_process_does_not_import_the_run(tmp_path: Path, command: str) -> None:
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO, encoding="utf-8")
    mcap = tmp_path / "run.mcap"
    if command == "demo":
        argv = ["demo", "--scenario", str(scenario), "--mcap", str(mcap)]
    else:
        argv = ["tui", "--emulate", str(scenario), "--mcap", str(mcap)]
    report = screen_process(argv)
    assert report["drawn"] and report["drawn"][0] >= 3  # snapshots from the engine drawn
    modules = report["modules"]
    assert "bench.tui.app" in modules and "bench.engine.client" in modules
    leaked = [m for m in modules if m.startswith(NEVER_IN_THE_SCREEN)]
    assert leaked == []
    assert mcap.stat().st_size > 0  # the engine ran and finished its log


def test_vote_labels_match_the_reference_method() -> None:
    # METHOD.md: v1 compares g12 with g23, v2 g23 with g13, v3 g12 with g13
    assert VOTE_SLOPES == ((0, 1), (1, 2), (0, 2)) == reference.VOTES
