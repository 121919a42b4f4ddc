"""The check kinds by name, in the order plans, ``bench accept --list`` and the report give
them, and running one check or judging a whole run.

Each family module registers its kinds in :data:`bench.acceptance.checks.base.KINDS` when
imported; importing this module imports every family, so its ``KINDS`` is complete.
"""

from __future__ import annotations

# every family registers its kinds in KINDS when imported
from bench.acceptance.checks import estimator, faults, frames, gradient  # noqa: F401
from bench.acceptance.checks.base import KINDS, CheckSpec, missing_column, not_measured
from bench.acceptance.model import Measurement, RunData

ORDER = (
    "gradient_error",
    "availability",
    "fault_detected",
    "no_frame_loss",
    "vote_failures",
    "gradient_jump",
    "event_count",
    "step_gradient",
    "latency",
    "sigma_coverage",
    "odometer_suspect",
    "odometer_flagged",
)
"""The kinds in the order plans, ``bench accept --list`` and the report name them."""

if set(ORDER) != set(KINDS):
    raise ImportError(f"check kinds registered {sorted(KINDS)} but ORDER names {sorted(ORDER)}")
for _name in ORDER:
    KINDS[_name] = KINDS.pop(_name)


def run_check(spec: CheckSpec, run: RunData) -> Measurement:
    """One check; a bug or bad data inside it is the bench's failure (verdict error)."""
    column = missing_column(spec, run)
    if column is not None:
        return not_measured(spec, "skip", f"these results have no {column} column")
    try:
        return KINDS[spec.kind].fn(spec, run)
    except Exception as exc:  # the other checks must still be measured and reported
        return not_measured(spec, "error", f"the check itself failed: {exc!r}")


def overall(measurements: list[Measurement]) -> str:
    """error if the bench failed anywhere, else fail if any check failed, else pass."""
    verdicts = {m.verdict for m in measurements}
    if "error" in verdicts:
        return "error"
    if "fail" in verdicts:
        return "fail"
    return "pass"
