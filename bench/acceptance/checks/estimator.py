"""Check kinds on the joint filter's own claims: its sigma, its odometer verdicts.

Pure functions of :class:`~bench.acceptance.model.RunData`, like every check; registered in
:data:`~bench.acceptance.checks.base.KINDS` when imported (by the registry).
"""

from __future__ import annotations

import numpy as np

from bench.acceptance.checks.base import (
    CheckSpec,
    Kind,
    Limit,
    Param,
    in_window,
    judge,
    not_measured,
    register,
)
from bench.acceptance.model import Measurement, RunData

SIGMAS = {
    "signed": ("gradient_signed", "gradient_sigma"),
    "smoothed": ("gradient_smoothed", "gradient_smoothed_sigma"),
}
"""The estimators that give a sigma: (gradient column, its 1-sigma column)."""


def check_sigma_coverage(spec: CheckSpec, run: RunData) -> Measurement:
    """Share of the window's given estimator gradients (``estimator``: signed or smoothed)
    whose error against truth is within ``n_sigma`` times their own sigma: an honest
    1-sigma covers about 95 % at 2 sigma. Withheld samples make no claim and are not counted."""
    if run.truth_gradient is None:
        return not_measured(spec, "error", "no emulator truth in this run (real board)")
    res = run.results
    column, sigma_column = SIGMAS[spec.get("estimator")]
    grad = res[column].astype(np.float64)
    sigma = res[sigma_column].astype(np.float64)
    truth = run.truth_at()
    sel = in_window(spec, run) & np.isfinite(grad) & np.isfinite(truth) & np.isfinite(sigma)
    if not sel.any():
        return judge(spec, None, "no estimator gradient given in the window")
    err = np.abs(grad[sel] - truth[sel])
    k = float(spec.get("n_sigma"))
    inside = err <= k * sigma[sel]
    wrong = int(np.count_nonzero(err > 1.0))
    value = float(inside.mean())
    return judge(
        spec,
        value,
        f"{int(inside.sum())} of {int(sel.sum())} given samples within {k:g} sigma"
        f"; {wrong} more than 1 permil off",
        samples=int(sel.sum()),
        median_sigma=float(np.median(sigma[sel])),
        confidently_wrong=wrong,
    )


def _spans(flag: np.ndarray, t: np.ndarray) -> tuple[int, float]:
    """(number of runs of True, longest run in s) of a flag over sample times t."""
    if not flag.any():
        return 0, 0.0
    f = flag.astype(np.int8)
    edges = np.diff(np.concatenate(([0], f, [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return len(starts), float((t[ends] - t[starts]).max())


def check_odometer_suspect(spec: CheckSpec, run: RunData) -> Measurement:
    """Share of the window's samples with SPEED_REF held suspect: at most (odometer_suspect,
    a clean odometer) or at least (odometer_flagged, a window where the wheels are known to
    slide or slip)."""
    sel = in_window(spec, run)
    if not sel.any():
        return judge(spec, None, "the window holds no sample")
    flag = run.results["odometer_suspect"][sel].astype(bool)
    count, longest = _spans(flag, run.time_s[sel])
    value = float(flag.mean())
    return judge(
        spec,
        value,
        f"odometer suspect in {value:.2%} of {int(sel.sum())} samples"
        f"; {count} spans, the longest {longest:.2f} s",
        spans=count,
        longest_s=longest,
    )


_KINDS: dict[str, Kind] = {
    "sigma_coverage": Kind(
        check_sigma_coverage,
        "fraction",
        {
            "estimator": Param(
                "choice",
                "signed",
                choices=tuple(SIGMAS),
                help="signed: the joint filter; "
                "smoothed: the model's smoother over the recorded run",
            ),
            "n_sigma": Param("number", 2.0, lo=0.0, help="coverage within this many sigma"),
            "min_fraction": Param("number", required=True, lo=0.0, hi=1.0),
            "warn_fraction": Param("number", lo=0.0, hi=1.0),
        },
        Limit("min_fraction", "warn_fraction", upper=False),
        needs_truth=True,
        summary="given estimator gradients within n_sigma of their gradient_sigma",
    ),
    "odometer_suspect": Kind(
        check_odometer_suspect,
        "fraction",
        {
            "max_fraction": Param("number", required=True, lo=0.0, hi=1.0),
            "warn_fraction": Param("number", lo=0.0, hi=1.0),
        },
        Limit("max_fraction", "warn_fraction", upper=True),
        summary="share of samples with SPEED_REF rejected as slip/slide (at most)",
    ),
    "odometer_flagged": Kind(
        check_odometer_suspect,
        "fraction",
        {
            "min_fraction": Param("number", required=True, lo=0.0, hi=1.0),
            "warn_fraction": Param("number", lo=0.0, hi=1.0),
        },
        Limit("min_fraction", "warn_fraction", upper=False),
        summary="share of samples with SPEED_REF rejected as slip/slide (at least)",
    ),
}

for _name, _kind in _KINDS.items():
    register(_name, _kind)
