"""A measurement's value, limits and window as the reports and the console print them."""

from __future__ import annotations

from bench.acceptance.model import VERDICTS, Measurement
from bench.acceptance.units import quantity


def format_value(m: Measurement) -> str:
    return quantity(m.value, m.unit)


def format_margin(m: Measurement) -> str:
    """The distance to the fail limit, in the check's unit (negative: failed by that much)."""
    return quantity(m.margin, m.unit)


def format_limits(m: Measurement) -> str:
    parts = []
    for key, v in m.limits.items():
        shown = quantity(v, m.unit)
        sign = "<=" if "max" in key else ">="
        parts.append(f"{'warn ' if key.startswith('warn') else ''}{sign} {shown}")
    return ", ".join(parts)


def window_text(m: Measurement) -> str:
    if m.from_s is None and m.to_s is None:
        return "whole run"
    return f"{m.from_s or 0:g} s to {'end' if m.to_s is None else f'{m.to_s:g} s'}"


def counts(measurements: list[Measurement]) -> dict[str, int]:
    return {v: sum(m.verdict == v for m in measurements) for v in VERDICTS}
