"""``bench replay run.mcap --compare [--config NEW] [--plan PLAN]``: would this run have
passed with other angles?

Before = the run's frames through the pipeline with the calibration it recorded (which
reproduces its recorded results bit for bit); after = the same frames with ``--config``.
Both sides go through one pipeline, so the only difference is the calibration. The answer
is one table: validity and vote failures both ways and, given a plan, every check's
verdict both ways. What a log cannot hold (emulator truth, the faults' record, operator
step windows) comes from the plan's scenario, simulated again (it is seeded).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rich import box
from rich.table import Table

from bench.acceptance.answers import schedule_steps
from bench.acceptance.checks.registry import run_check
from bench.acceptance.expectation import result, status_of
from bench.acceptance.feeds import BATCH_FRAMES, fault_infos
from bench.acceptance.model import Measurement, RunData
from bench.acceptance.plan import Plan
from bench.acceptance.runner import Collector, count_logged_frames
from bench.config import Config
from bench.pipeline.stats import Stats
from bench.pipeline.steps import Pipeline
from bench.replay.run import run_steps

LABEL_WIDTH = 34
VALUE_WIDTH = 19
"""Column widths: label + two values + borders stay within 80 columns."""


@dataclass
class Side:
    """One way of replaying the run: its calibration, results, events and, with a plan,
    every check's measurement."""

    label: str
    config: Config
    results: np.ndarray
    events: np.ndarray
    stats: Stats
    measurements: list[Measurement] = field(default_factory=list)


def replay_side(path: str | Path, config: Config, label: str) -> Side:
    """The run's raw frames through a fresh pipeline with ``config``."""
    from bench.mcaplog.source import McapFrameSource

    source = McapFrameSource(path)
    collector = Collector()
    pipeline = Pipeline(config)
    try:
        for step in run_steps(pipeline, source.batches(BATCH_FRAMES)):
            collector.write(step)
    finally:
        source.close()
    return Side(label, config, collector.results(), collector.events(), pipeline.stats)


def plan_run_data(plan: Plan, side: Side, path: str | Path, sim: Any) -> RunData:
    """What the plan's checks measure, from one side's results and events."""
    res = side.results
    if sim is not None:
        n_ref, rate = int(sim.scenario.counter0), float(sim.scenario.sample_rate_hz)
    else:
        n_ref, rate = (int(res["n"][0]) if len(res) else 0), float(side.config.sample_rate_hz)
    emulated = sim is not None
    return RunData(
        results=res,
        events=side.events,
        rate_hz=rate,
        n_ref=n_ref,
        truth_gradient=sim.truth["gradient_permil"].copy() if emulated else None,
        faults=fault_infos(sim, plan.link) if emulated else (),
        frames_sent=len(sim.frames) if emulated and plan.link == "can" else None,
        frames_received=side.stats.frames,
        frames_logged=count_logged_frames(Path(path)),
        steps=schedule_steps(plan.steps, None) if emulated else (),
        mode="replay",
        link=plan.link,
    )


def measure(plan: Plan, sides: list[Side], path: str | Path) -> None:
    """Every check of ``plan`` on each side (in place)."""
    sim = None
    if plan.scenario is not None:
        from devices.emulator import simulate

        sim = simulate(plan.scenario)
    for side in sides:
        run = plan_run_data(plan, side, path, sim)
        side.measurements = [run_check(c, run) for c in plan.checks]


def _pct(count: int, total: int) -> str:
    return f"{100.0 * count / total:.2f} %" if total else "-"


def _available(side: Side) -> str:
    """Share of results with a gradient from the bench's estimator."""
    res = side.results
    return _pct(int(np.count_nonzero(np.isfinite(res["gradient_signed"]))), len(res))


def _short_value(m: Measurement) -> str:
    if m.value is None or not np.isfinite(m.value):
        return m.verdict.upper()
    if m.unit == "fraction":
        return f"{m.verdict.upper()} {m.value:.2%}"
    return f"{m.verdict.upper()} {m.value:.3g} {m.unit}"


def fit(text: str, width: int = LABEL_WIDTH) -> str:
    """``text`` cut in the middle to ``width``: check names often differ only at the end."""
    if len(text) <= width:
        return text
    tail = width // 3
    return text[: width - tail - 1] + "…" + text[-tail:]


def _angles(config: Config) -> str:
    return "/".join(f"{c.angle_deg:g}" for c in config.channels)


def comparison_table(
    before: Side, after: Side, rows_differing: int, plan: Plan | None = None
) -> Table:
    """The one table: validity both ways, then each check's verdict both ways."""
    table = Table(
        title="would this run have passed with the other calibration?",
        box=box.SIMPLE_HEAD,
        pad_edge=False,
    )
    table.add_column("", no_wrap=True, overflow="ellipsis", max_width=LABEL_WIDTH)
    for side in (before, after):
        table.add_column(
            side.label, no_wrap=True, overflow="ellipsis", max_width=VALUE_WIDTH, justify="right"
        )
    b, a = before.stats, after.stats
    table.add_row("angles ch1/ch2/ch3, deg", _angles(before.config), _angles(after.config))
    table.add_row(
        "vote tolerance, permil",
        f"{before.config.tolerance_permil:g}",
        f"{after.config.tolerance_permil:g}",
    )
    table.add_row("samples", str(b.samples), str(a.samples))
    table.add_row("valid (device)", _pct(b.valid, b.samples), _pct(a.valid, a.samples))
    for k in range(3):
        table.add_row(
            f"vote v{k + 1} failing",
            _pct(b.vote_failures[k], b.samples),
            _pct(a.vote_failures[k], a.samples),
        )
    table.add_row("estimator gradient available", _available(before), _available(after))
    table.add_row("degraded (estimator)", _pct(b.degraded, b.samples), _pct(a.degraded, a.samples))
    table.add_row("results differing", "-", f"{rows_differing} rows", end_section=True)
    if plan is None:
        return table
    pairs = list(zip(before.measurements, after.measurements, strict=True))
    for i, (mb, ma) in enumerate(pairs):
        style = "" if status_of(mb) == status_of(ma) else "bold"
        last = i == len(pairs) - 1
        table.add_row(
            fit(mb.name), _short_value(mb), _short_value(ma), style=style, end_section=last
        )
    rb, ra = result(before.measurements), result(after.measurements)
    table.add_row(
        fit(f"plan {plan.name} (expects {plan.expect})"),
        rb.upper(),
        ra.upper(),
        style="bold",
    )
    return table
