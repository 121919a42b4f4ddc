"""Every shipped plan runs headless and gives the verdict it states, check by check; its
run.mcap, replayed through a fresh pipeline, gives the same measurements."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from bench.acceptance.plan import load_plan, shipped_plans
from bench.acceptance.runner import Options, remeasure, run_plan


@pytest.mark.parametrize("path", shipped_plans(), ids=lambda p: p.stem)
def test_shipped_plan_gives_its_expected_verdict(path: Path, tmp_path: Path) -> None:
    plan = load_plan(path)
    start = time.perf_counter()
    outcome = run_plan(plan, Options(out_dir=tmp_path, plots=False, command="pytest"))
    elapsed = time.perf_counter() - start
    assert outcome.error is None
    got = {m.name: m.verdict for m in outcome.measurements}
    want = {c.name: c.expect or "pass" for c in plan.checks}
    wrong = {
        m.name: f"{m.verdict} (plan says {want[m.name]}): {m.detail}"
        for m in outcome.measurements
        if m.verdict != want[m.name]
    }
    assert got == want, wrong
    assert outcome.verdict == plan.expect  # what the device did
    assert outcome.result == "pass" and outcome.exit_code == 0  # as the plan designed it
    for name in ("junit.xml", "record.json", "report.html", "run.mcap", "scenario.toml"):
        assert (tmp_path / name).stat().st_size > 0

    replayed = remeasure(outcome)
    for before, after in zip(outcome.measurements, replayed, strict=True):
        assert (after.name, after.value, after.verdict) == (
            before.name,
            before.value,
            before.verdict,
        )
    print(f"{plan.name}: {outcome.verdict} in {elapsed:.2f} s")
