"""What every check kind is made of: its plan keys, its limit, and judging a value against it.

Every limit is data from the plan; a check never decides a limit itself.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.acceptance.model import Measurement, RunData
from bench.acceptance.units import quantity

ESTIMATORS = {
    # name: (result column, compare with |truth|: the column has no sign)
    "reference": ("gradient", True),
    "signed": ("gradient_signed", False),
    "magnitude": ("gradient_ls", True),
    # the explicit model's RTS smoother over the whole recorded run (bench.acceptance.smoothing)
    "smoothed": ("gradient_smoothed", False),
}


@dataclass(frozen=True, slots=True)
class Param:
    """One key a check kind accepts, with its type and range (validated by the plan loader)."""

    type: str  # number | integer | bool | choice | events | string
    default: Any = None
    required: bool = False
    lo: float | None = None
    hi: float | None = None
    choices: tuple[Any, ...] = ()
    help: str = ""


ESTIMATOR_PARAM = Param(
    "choice",
    "reference",
    choices=tuple(ESTIMATORS),
    help="reference: the device's method; signed: the bench's estimator; magnitude: LS; "
    "smoothed: the model's smoother over the recorded run",
)


@dataclass(frozen=True, slots=True)
class CheckSpec:
    """A check as the plan states it (validated)."""

    index: int  # 1-based position in [[checks]]
    name: str
    kind: str
    params: dict[str, Any]
    from_s: float | None = None
    to_s: float | None = None
    expect: str | None = None

    def get(self, key: str) -> Any:
        return self.params.get(key, KINDS[self.kind].params[key].default)


@dataclass(frozen=True, slots=True)
class Limit:
    """How a kind's value is judged: against a maximum or a minimum, with a warning band."""

    key: str  # the plan key holding the fail limit
    warn_key: str | None
    upper: bool  # True: value must be <= limit; False: value must be >= limit


@dataclass(frozen=True, slots=True)
class Kind:
    fn: Callable[[CheckSpec, RunData], Measurement]
    unit: str
    params: dict[str, Param]
    limit: Limit
    needs_truth: bool = False
    needs_steps: bool = False
    summary: str = ""


def in_window(spec: CheckSpec, run: RunData) -> np.ndarray:
    """Results inside the check's run-time window."""
    t = run.time_s
    sel = run.k >= 0
    if spec.from_s is not None:
        sel &= t >= spec.from_s - 1e-9
    if spec.to_s is not None:
        sel &= t < spec.to_s - 1e-9
    return sel


def expected_samples(spec: CheckSpec, run: RunData) -> int:
    """Sampling instants the window spans (lost ones included)."""
    total = run.n_samples
    lo = 0 if spec.from_s is None else math.ceil(spec.from_s * run.rate_hz - 1e-6)
    hi = total if spec.to_s is None else min(total, math.ceil(spec.to_s * run.rate_hz - 1e-6))
    return max(0, hi - max(lo, 0))


def fmt_value(v: float | None, unit: str) -> str:
    return quantity(v, unit, digits=4)


def judge(spec: CheckSpec, value: float | None, detail: str, **extra: Any) -> Measurement:
    """Compare a value with the check's limit and warning limit; say by how much it missed."""
    kind = KINDS[spec.kind]
    lim = kind.limit
    limit = spec.get(lim.key)
    warn = spec.get(lim.warn_key) if lim.warn_key else None
    limits: dict[str, float] = {}
    name_fail, name_warn = ("max", "warn_max") if lim.upper else ("min", "warn_min")
    limits[name_fail] = limit
    if warn is not None:
        limits[name_warn] = warn
    unit = kind.unit
    if value is None or not math.isfinite(value):
        verdict, margin = "fail", None
        text = f"nothing to measure: {detail}" if detail else "nothing to measure"
    else:
        margin = (limit - value) if lim.upper else (value - limit)
        cmp_fail = ">" if lim.upper else "<"
        if margin < 0:
            verdict = "fail"
            text = (
                f"{fmt_value(value, unit)} {cmp_fail} limit {fmt_value(limit, unit)} "
                f"(by {fmt_value(-margin, unit)})"
            )
        elif warn is not None and ((value > warn) if lim.upper else (value < warn)):
            verdict = "warn"
            text = (
                f"{fmt_value(value, unit)} within limit {fmt_value(limit, unit)} but past the "
                f"warning limit {fmt_value(warn, unit)} (margin {fmt_value(margin, unit)})"
            )
        else:
            verdict = "pass"
            text = f"{fmt_value(value, unit)} within limit {fmt_value(limit, unit)}"
        if detail:
            text += f"; {detail}"
    return Measurement(
        spec.name,
        spec.kind,
        value,
        unit,
        limits,
        verdict,
        text,
        spec.from_s,
        spec.to_s,
        margin,
        spec.expect,
        extra,
    )


def not_measured(spec: CheckSpec, verdict: str, why: str, **extra: Any) -> Measurement:
    """A check that could not be measured: 'skip' (not meaningful here) or 'error'."""
    kind = KINDS[spec.kind]
    limits = {("max" if kind.limit.upper else "min"): spec.get(kind.limit.key)}
    return Measurement(
        spec.name,
        spec.kind,
        None,
        kind.unit,
        limits,
        verdict,
        why,
        spec.from_s,
        spec.to_s,
        None,
        spec.expect,
        extra,
    )


def wants_smoothing(specs: list[CheckSpec] | tuple[CheckSpec, ...]) -> bool:
    """Some check judges the smoothed gradient: the run must be smoothed before measuring."""
    return any(c.params.get("estimator") == "smoothed" for c in specs)


def missing_column(spec: CheckSpec, run: RunData) -> str | None:
    """The result column the check's estimator names when the results lack it (a smoothed
    check on results nobody smoothed: `bench replay --compare` judges the filtered ones)."""
    name = spec.params.get("estimator")
    if name is None:
        return None
    column = ESTIMATORS[name][0]
    return None if column in (run.results.dtype.names or ()) else column


def gradient_of(spec: CheckSpec, run: RunData) -> tuple[np.ndarray, bool, str]:
    column, unsigned = ESTIMATORS[spec.get("estimator")]
    return run.results[column].astype(np.float64), unsigned, column


KINDS: dict[str, Kind] = {}
"""Every check kind by name; the family modules fill it through :func:`register` (import
:mod:`bench.acceptance.checks.registry` to have them all, in their order)."""


def register(name: str, kind: Kind) -> None:
    """Add a check kind (one name, one kind: a second registration is a bug)."""
    if name in KINDS:
        raise ValueError(f"check kind {name!r} registered twice")
    KINDS[name] = kind
