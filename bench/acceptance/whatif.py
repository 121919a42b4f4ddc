"""``bench replay run.mcap --compare [--config NEW] [--plan PLAN]``: would this run have
passed with other angles?

Before = the run's frames through the pipeline with the calibration it recorded (which
reproduces its recorded results bit for bit); after = the same frames with ``--config``.
Both sides go through one pipeline, so the only difference is the calibration. The answer
is one table: validity and vote failures both ways and, given a plan, every check's
verdict both ways.

What the checks judge is the recording. Frames lost are the frames the recording says were
lost (its queue drops, its writer's count against the frames in the file, the kernel's
socket overflows), not frames of the log counted against a simulation. What a log cannot
hold (emulator truth, the faults' record, operator step windows) comes from the plan's
scenario, simulated again (it is seeded), but only when the log is a run of that scenario
(the scenario it recorded is the plan's); otherwise the checks that need it are skipped.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rich import box
from rich.table import Table

from bench.acceptance.answers import schedule_steps
from bench.acceptance.checks.base import KINDS, not_measured
from bench.acceptance.checks.registry import run_check
from bench.acceptance.expectation import result, status_of
from bench.acceptance.feeds import BATCH_FRAMES, fault_infos
from bench.acceptance.model import Measurement, RunData
from bench.acceptance.plan import Plan
from bench.acceptance.runner import Collector, count_logged_frames
from bench.config import Config
from bench.pipeline.stats import Stats
from bench.pipeline.steps import Pipeline
from bench.records.events import EventKind
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


def same_calibration(a: Config, b: Config) -> bool:
    """True when the pipeline computes the same with either (only where they came from
    differs): one side's replay then serves both."""
    return dataclasses.replace(a, source="", path=None) == dataclasses.replace(
        b, source="", path=None
    )


@dataclass(frozen=True, slots=True)
class Recording:
    """What a log says of its own run: the frames its pipeline was given, the frames in the
    file, the frames its queues dropped, and whether it is a run of the plan's scenario."""

    frames_received: int | None  # the summary's count (None: no summary, a cut file)
    frames_logged: int
    frames_dropped: int  # DROPPED events: the acquisition queue's and the writer's
    of_plan: bool  # the scenario it recorded is the plan's (so the plan's truth applies)
    source: str  # what it recorded, for the note when it is not the plan's run


def read_recording(plan: Plan, path: str | Path) -> Recording:
    from bench.mcaplog.recorded import read_attachments, read_events, read_metadata

    meta = read_metadata(path)
    received = meta.get("summary", {}).get("frames")
    dropped = sum(
        int(e.get("value") or 0) for e in read_events(path) if e.get("kind") == EventKind.DROPPED
    )
    of_plan = False
    if plan.scenario is not None:
        recorded = read_attachments(path).get("scenario.toml")
        of_plan = recorded is not None and recorded == plan.scenario_toml().encode()
    return Recording(
        frames_received=int(received) if received is not None and received.isdigit() else None,
        frames_logged=count_logged_frames(Path(path)),
        frames_dropped=dropped,
        of_plan=of_plan,
        source=meta.get("run", {}).get("source", "an unknown source"),
    )


def plan_run_data(plan: Plan, side: Side, recording: Recording, sim: Any) -> RunData:
    """What the plan's checks measure, from one side's results and events and what the
    recording says of its frames; ``sim`` is the plan's scenario when the log is its run."""
    res = side.results
    if sim is not None:
        n_ref, rate = int(sim.scenario.counter0), float(sim.scenario.sample_rate_hz)
    else:
        n_ref, rate = (int(res["n"][0]) if len(res) else 0), float(side.config.sample_rate_hz)
    emulated = sim is not None
    received = recording.frames_received
    return RunData(
        results=res,
        events=side.events,
        rate_hz=rate,
        n_ref=n_ref,
        truth_gradient=sim.truth["gradient_permil"].copy() if emulated else None,
        faults=fault_infos(sim, plan.link) if emulated else (),
        frames_sent=None,  # what was sent is not in a log: its own losses are
        frames_received=received if received is not None else side.stats.frames,
        frames_logged=recording.frames_logged,
        frames_dropped=recording.frames_dropped,
        steps=schedule_steps(plan.steps, None) if emulated else (),
        mode="replay",
        link=plan.link,
    )


def measure(plan: Plan, sides: list[Side], path: str | Path) -> str | None:
    """Every check of ``plan`` on each side (in place); a note when the log is not a run of
    the plan's scenario (the checks that need its truth or steps are skipped then)."""
    recording = read_recording(plan, path)
    sim = None
    if plan.scenario is not None and recording.of_plan:
        from devices.emulator import simulate

        sim = simulate(plan.scenario)
    foreign = plan.scenario is not None and not recording.of_plan
    why = (
        f"{Path(path).name} is not a run of plan {plan.name}'s scenario: no truth, faults or steps"
    )
    for side in sides:
        run = plan_run_data(plan, side, recording, sim)
        side.measurements = [
            not_measured(c, "skip", why)
            if foreign and (KINDS[c.kind].needs_truth or KINDS[c.kind].needs_steps)
            else run_check(c, run)
            for c in plan.checks
        ]
    if not foreign:
        return None
    return (
        f"note: {Path(path).name} recorded {recording.source}, not plan {plan.name}'s "
        "scenario: the checks that need its truth, faults or steps are skipped"
    )


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
