"""argparse types for numbers an operator types: range-checked, with the range in the message."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def bounded_float(
    lo: float, hi: float, unit: str = "", *, lo_included: bool = False
) -> Callable[[str], float]:
    """A float in (lo, hi] (``lo_included``: [lo, hi]): argparse shows ``argument --x: must
    be in (lo, hi] unit``."""
    shown = f"{'[' if lo_included else '('}{lo:g}, {hi:g}]" + (f" {unit}" if unit else "")

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected a number in {shown}, got {text!r}"
            ) from None
        above = lo <= value if lo_included else lo < value
        if not (math.isfinite(value) and above and value <= hi):
            raise argparse.ArgumentTypeError(f"must be in {shown}, got {text!r}")
        return value

    parse.__name__ = "number"
    return parse


SECONDS = bounded_float(0.0, 1e7, "s")
"""A run's length: positive, finite, at most ~115 days."""
SPEED = bounded_float(0.0, 1000.0, "x real time")
"""A virtual board's time factor."""
RATE = bounded_float(0.0, 1000.0, "x recorded speed")
"""A recorded log's replay speed factor."""
LAG = bounded_float(0.0, 10.0, "s", lo_included=True)
"""The live model's fixed lag (`--lag`): its smoother's cost per block grows with it."""


def add_lag_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--lag",
        type=LAG,
        metavar="SECONDS",
        help="run the explicit model live (its own thread) and smooth its gradient over the "
        "last SECONDS (0-10; 0: the filter alone): a second plot line, a model panel (wheel "
        "error, compliance, biases), /bench/model in the log",
    )


OFFSET = bounded_float(0.0, 1e7, "s", lo_included=True)
"""Seconds into a log: zero or more."""
