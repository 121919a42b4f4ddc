"""A measurement's value, limits and window as the reports and the console print them."""

from __future__ import annotations

import math

from bench.acceptance.model import VERDICTS, Measurement


def format_value(m: Measurement) -> str:
    if m.value is None or not math.isfinite(m.value):
        return "n/a"
    if m.unit == "fraction":
        return f"{m.value:.4%}"
    return f"{m.value:.6g} {m.unit}"


def format_limits(m: Measurement) -> str:
    parts = []
    for key, v in m.limits.items():
        shown = f"{v:.4%}" if m.unit == "fraction" else f"{v:g} {m.unit}"
        sign = "<=" if "max" in key else ">="
        parts.append(f"{'warn ' if key.startswith('warn') else ''}{sign} {shown}")
    return ", ".join(parts)


def window_text(m: Measurement) -> str:
    if m.from_s is None and m.to_s is None:
        return "whole run"
    return f"{m.from_s or 0:g} s to {'end' if m.to_s is None else f'{m.to_s:g} s'}"


def counts(measurements: list[Measurement]) -> dict[str, int]:
    return {v: sum(m.verdict == v for m in measurements) for v in VERDICTS}
