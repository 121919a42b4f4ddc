"""Headless acceptance runs: plans (scenario + limits as data), checks, verdicts, reports.

    plan = load_plan("level")                       # bench/plans/level.toml (plan.py)
    outcome = run_plan(plan, Options(out_dir=Path("out")))   # runner.py
    outcome.verdict, outcome.exit_code              # "pass" | "fail" | "error", 0 | 1 | 2

model.py holds what a run measures (RunData, Measurement), outcome.py the finished run;
checks/ the check kinds, one module per family, by name in checks/registry.py; answers.py
the operator steps; feeds.py what an emulated run feeds the pipeline; report.py junit.xml,
record.json, the plots and report.html. See docs/ACCEPTANCE.md for the plan format, the
check kinds and the run modes.
"""
