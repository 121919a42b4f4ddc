"""Did the run behave as the plan designed it? Verdicts judged against each check's ``expect``.

A check's *verdict* says what the device did (pass, warn, fail, ...); its *status* says
whether that is what the plan meant: a plan written to show a weakness (``reference-sign``:
the device cannot give a down-grade's sign) has checks with ``expect = "fail"``, and such a
check failing is the plan working -- "behaved as designed", no failure in junit.xml, exit 0.
The same check passing means the plan no longer shows what it was written for: a failure.

Statuses: ``ok`` (pass/warn, as meant), ``as designed`` (failed, meant to fail), ``not as
designed`` (meant to fail, did not), ``failure`` (failed, not meant to), ``error`` (not
measured: the bench failed), ``skipped``. A check expected to warn that passes is ``ok``:
a warning limit is a margin, not a requirement.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from bench.acceptance.model import EXIT_CODES

__all__ = ["EXIT_CODES", "check_status", "expectation_text", "plan_line", "result", "status_of"]

FAILING = frozenset({"not as designed", "failure"})


def check_status(verdict: str, expect: str | None) -> str:
    if verdict == "error":
        return "error"
    if expect == "fail":
        return "as designed" if verdict == "fail" else "not as designed"
    if verdict == "fail":
        return "failure"
    if verdict == "skip":
        return "skipped"
    return "ok"


def status_of(m: Any) -> str:
    """The status of a Measurement (anything with ``verdict`` and ``expect``)."""
    return check_status(m.verdict, m.expect)


def result(measurements: Iterable[Any], error: str | None = None) -> str:
    """The run's result: error if the bench failed, fail if any check did not behave as
    the plan designed it, else pass (a plan meant to fail that failed as meant passes)."""
    statuses = {status_of(m) for m in measurements}
    if error is not None or "error" in statuses:
        return "error"
    return "fail" if statuses & FAILING else "pass"


def expectation_text(m: Any) -> str:
    """One line on the check's expectation, for junit.xml, the console and the report."""
    status = status_of(m)
    got = m.verdict.upper()
    if status == "as designed":
        return f"behaved as designed: expected to FAIL, and it did ({got})"
    if status == "not as designed":
        return f"NOT as designed: expected to FAIL, but it gave {got}"
    if m.expect is not None and m.expect != m.verdict:
        return f"expected {m.expect.upper()}, gave {got}"
    return f"expected {(m.expect or 'pass').upper()}, gave {got}"


def plan_line(plan_name: str, plan_expect: str, measurements: list[Any], res: str) -> str:
    """The closing sentence of a run: its result and, for a plan meant to fail, whether it
    failed the way it was designed to."""
    designed = [m.name for m in measurements if status_of(m) == "as designed"]
    undesigned = [m.name for m in measurements if status_of(m) == "not as designed"]
    unexpected = [m.name for m in measurements if status_of(m) == "failure"]
    if res == "error":
        return f"plan {plan_name}: ERROR (the bench could not measure every check)"
    parts = []
    if res == "pass" and plan_expect == "fail":
        parts.append(f"behaved as designed: {len(designed)} check(s) failed as the plan expects")
    if undesigned:
        parts.append(f"not as designed: {', '.join(undesigned)} did not fail as expected")
    if unexpected:
        parts.append(f"failed: {', '.join(unexpected)}")
    tail = f" ({'; '.join(parts)})" if parts else ""
    return f"plan {plan_name}: {res.upper()}{tail}"
