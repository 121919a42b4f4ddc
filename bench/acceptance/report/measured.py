"""How a measurement reads in the tables (console, junit.xml, report.html).

Most checks measure the quantity they judge. A step check judges an *error* (reading minus
the step's expected gradient), but what an operator reads off a tilt table is the device's
*reading*: the measured column shows the reading, with the error it was judged on beside it.
"""

from __future__ import annotations

from typing import Any

from bench.acceptance.report.text import format_value


def step_reading(m: Any) -> dict[str, Any] | None:
    """For a step check: the step that decided it (the worst one) with its mean reading,
    expected value and error; None for other checks or when no step was measured."""
    if m.kind != "step_gradient":
        return None
    steps = [s for s in m.extra.get("steps", []) if isinstance(s.get("mean"), float)]
    if not steps:
        return None
    return max(steps, key=lambda s: s["error"])


def measured_text(m: Any) -> str:
    """The measured column: a step check's reading and its error, else the judged value."""
    s = step_reading(m)
    if s is None:
        return format_value(m)
    return f"{s['mean']:.6g} {m.unit} (error {format_value(m)})"


def reading_extra(m: Any) -> dict[str, Any]:
    """Record fields for the reading behind a step check's error (empty for other checks)."""
    s = step_reading(m)
    if s is None:
        return {}
    return {"reading": s["mean"], "reading_step": s["step"], "reading_expected": s["expected"]}
