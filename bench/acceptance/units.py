"""How a check's numbers read wherever a person reads them (console, junit.xml, report.html).

One convention: a number, a space, its unit; a fraction reads as a percentage ("16.9167 %",
never "0.169167 fraction" or a bare 0.1692). record.json is for machines and keeps the
number in the check's own unit beside a ``unit`` field.
"""

from __future__ import annotations

import math


def quantity(value: float | None, unit: str, digits: int = 6) -> str:
    """``value`` in ``unit`` for a person: "n/a" when there is none."""
    if value is None or not math.isfinite(value):
        return "n/a"
    if unit == "fraction":
        return f"{100.0 * value:.{digits}g} %"
    return f"{value:.{digits}g} {unit}"
