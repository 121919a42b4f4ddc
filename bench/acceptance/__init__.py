"""Headless acceptance runs: plans (scenario + limits as data), checks, verdicts, reports.

    plan = load_plan("level")                       # bench/plans/level.toml
    outcome = run_plan(plan, Options(out_dir=Path("out")))
    outcome.verdict, outcome.exit_code              # "pass" | "fail" | "error", 0 | 1 | 2

See docs/ACCEPTANCE.md for the plan format, the check kinds and the run modes.
"""

from bench.acceptance.checks import KINDS, Measurement, RunData
from bench.acceptance.plan import Plan, load_plan, parse_plan, shipped_plans
from bench.acceptance.runner import Answer, Options, Outcome, load_answers, remeasure, run_plan

__all__ = [
    "KINDS",
    "Answer",
    "Measurement",
    "Options",
    "Outcome",
    "Plan",
    "RunData",
    "load_answers",
    "load_plan",
    "parse_plan",
    "remeasure",
    "run_plan",
    "shipped_plans",
]
