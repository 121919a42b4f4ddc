"""The TUI's panels, one per module; each has a ``show(...)`` fed from a Snapshot.

Formatting helpers shared by the panels live here: one way to print a missing value,
a per mille figure, a byte count, so the whole screen reads alike.
"""

from __future__ import annotations

import math

import numpy as np
from rich.text import Text

MISSING = "—"


def num(value: float, fmt: str = ".3f", missing: str = MISSING) -> str:
    """A float for display; NaN/inf/None become ``missing``."""
    if value is None or not math.isfinite(float(value)):
        return missing
    return format(float(value), fmt)


def labelled(lines: list[tuple[str, Text | str]], width: int = 8) -> Text:
    """One line per (label, value), the label bold in a column ``width`` wide; long lines
    end in an ellipsis."""
    out = Text(no_wrap=True, overflow="ellipsis")
    for label, value in lines:
        if out:
            out.append("\n")
        out.append(f"{label:<{width}}", style="bold")
        out.append(value)
    return out


def size_text(n: float | None) -> str:
    if n is None or not math.isfinite(float(n)):
        return MISSING
    n = float(n)
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


def duration_text(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(float(seconds)) or seconds < 0:
        return MISSING
    s = int(seconds)
    return f"{s // 3600:d}:{s // 60 % 60:02d}:{s % 60:02d}"


def grade_state(row: np.void | None) -> str:
    """valid (3/3 votes), degraded (1-2 votes: still a result), invalid (none), or none."""
    if row is None:
        return "none"
    passed = int(np.count_nonzero(row["votes"]))
    if passed == 3:
        return "valid"
    return "degraded" if passed else "invalid"
