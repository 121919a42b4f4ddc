"""Checks on the gradient itself: its error against truth, its availability, its jumps, and
the operator steps' measured against expected values."""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.acceptance.checks.base import (
    ESTIMATOR_PARAM,
    CheckSpec,
    Kind,
    Limit,
    Param,
    expected_samples,
    gradient_of,
    in_window,
    judge,
    not_measured,
    register,
)
from bench.acceptance.model import Measurement, RunData


def check_gradient_error(spec: CheckSpec, run: RunData) -> Measurement:
    """|gradient - truth| per sample over the window, reduced by `statistic`.

    The reference method and the least-squares magnitude carry no sign (METHOD.md section
    4), so by default (`truth = "auto"`) they are compared with |truth| and the signed
    estimator with truth itself; `truth = "signed"` holds an unsigned method to the sign.
    Samples without a gradient are not errors here: availability measures them."""
    if run.truth_gradient is None:
        return not_measured(spec, "error", "no emulator truth in this run (real board)")
    grad, unsigned, column = gradient_of(spec, run)
    truth = run.truth_at()
    mode = spec.get("truth")
    if mode == "magnitude" or (mode == "auto" and unsigned):
        unsigned = True
        truth = np.abs(truth)
    else:
        unsigned = False
    sel = in_window(spec, run) & np.isfinite(grad) & np.isfinite(truth)
    err = grad[sel] - truth[sel]
    stat = spec.get("statistic")
    extra: dict[str, Any] = {"column": column, "samples": int(sel.sum())}
    if len(err) == 0:
        if spec.get("allow_empty"):
            return judge(spec, 0.0, f"no {column} reported in the window, so none was wrong")
        return judge(spec, None, f"no sample with a {column} in the window", **extra)
    a = np.abs(err)
    worst = int(np.argmax(a))
    extra.update(
        max_abs=float(a.max()),
        rms=float(np.sqrt(np.mean(err * err))),
        bias=float(err.mean()),
        p99=float(np.percentile(a, 99)),
        worst_at_s=float(run.time_s[sel][worst]),
    )
    value = {
        "max": extra["max_abs"],
        "p99": extra["p99"],
        "p95": float(np.percentile(a, 95)),
        "rms": extra["rms"],
        "bias": abs(extra["bias"]),
        "std": float(err.std()),
    }[stat]
    ref = "|truth|" if unsigned else "truth"
    what = f"mean of {column} - {ref}" if stat == "bias" else f"{stat} of |{column} - {ref}|"
    detail = (
        f"{what} over {len(err)} samples"
        f"; worst {extra['max_abs']:.4g} permil at {extra['worst_at_s']:.3f} s"
    )
    return judge(spec, value, detail, **extra)


def check_availability(spec: CheckSpec, run: RunData) -> Measurement:
    """Fraction of the window's sampling instants with a gradient (lost samples count as
    unavailable: the denominator is the instants the window spans, not the results)."""
    grad, _, column = gradient_of(spec, run)
    ok = run.results["valid"] if spec.get("estimator") == "reference" else np.isfinite(grad)
    sel = in_window(spec, run)
    if run.truth_gradient is not None:
        sel &= run.k < len(run.truth_gradient)
    expected = expected_samples(spec, run)
    have = int(np.unique(run.k[sel & ok]).size)
    if expected == 0:
        return judge(spec, None, "the window holds no sampling instant")
    value = have / expected
    return judge(
        spec,
        value,
        f"{have} of {expected} samples with a {column}",
        available=have,
        expected=expected,
        column=column,
    )


def check_gradient_jump(spec: CheckSpec, run: RunData) -> Measurement:
    """Largest change of the gradient between consecutive sampling instants that both have
    one: what a consumer of the gradient (a brake controller) would see as a step."""
    grad, _, column = gradient_of(spec, run)
    sel = in_window(spec, run)
    k = run.k[sel]
    g = grad[sel]
    ok = np.isfinite(g)
    k, g = k[ok], g[ok]
    if len(g) < 2:
        return judge(spec, None, f"fewer than two samples with a {column} in the window")
    consecutive = np.diff(k) == 1
    d = np.abs(np.diff(g))[consecutive]
    if len(d) == 0:
        return judge(spec, None, "no two consecutive samples with a gradient")
    i = int(np.argmax(d))
    at = float(k[:-1][consecutive][i] / run.rate_hz)
    return judge(
        spec,
        float(d[i]),
        f"largest step of {column} at {at:.3f} s over {len(d)} consecutive pairs",
        at_s=at,
        column=column,
    )


def check_step_gradient(spec: CheckSpec, run: RunData) -> Measurement:
    """Operator steps: the gradient measured in each step's window against the gradient the
    step expected (the operator's reference reading when one was entered). `statistic` =
    "mean": error of the window's mean (a tilt-table calibration point); "max": worst
    single-sample error. The value is the worst step's."""
    steps = [s for s in run.steps if spec.get("step") in (None, s.index)]
    if not steps:
        return not_measured(spec, "error", "the run has no operator steps to measure")
    grad, unsigned, column = gradient_of(spec, run)
    t = run.time_s
    per_step = []
    worst: float | None = -1.0
    texts = []
    for s in steps:
        if s.answer == "skip":
            per_step.append({"step": s.index, "answer": "skip"})
            texts.append(f"step {s.index} skipped by the operator")
            worst = None
            continue
        sel = (t >= s.from_s) & (t < s.to_s) & (run.k >= 0) & np.isfinite(grad)
        expected = abs(s.expected_permil) if unsigned else s.expected_permil
        g = grad[sel]
        if len(g) == 0:
            per_step.append({"step": s.index, "expected": expected, "samples": 0})
            texts.append(f"step {s.index}: no sample with a {column}")
            worst = None
            continue
        mean = float(g.mean())
        err = (
            abs(mean - expected)
            if spec.get("statistic") == "mean"
            else float(np.abs(g - expected).max())
        )
        per_step.append(
            {
                "step": s.index,
                "expected": expected,
                "mean": mean,
                "std": float(g.std()),
                "error": err,
                "samples": len(g),
                "window_s": [s.from_s, s.to_s],
            }
        )
        texts.append(f"step {s.index}: {mean:.4g} vs {expected:g} permil (error {err:.4g})")
        if worst is not None:
            worst = max(worst, err)
    return judge(spec, worst, "; ".join(texts), steps=per_step, column=column)


register(
    "gradient_error",
    Kind(
        check_gradient_error,
        "permil",
        {
            "estimator": ESTIMATOR_PARAM,
            "statistic": Param(
                "choice", "max", choices=("max", "p99", "p95", "rms", "bias", "std")
            ),
            "truth": Param("choice", "auto", choices=("auto", "signed", "magnitude")),
            "allow_empty": Param(
                "bool", False, help="no gradient at all in the window passes (fail-safe)"
            ),
            "max_permil": Param("number", required=True, lo=0.0),
            "warn_permil": Param("number", lo=0.0),
        },
        Limit("max_permil", "warn_permil", upper=True),
        needs_truth=True,
        summary="|gradient - truth| per sample in a window",
    ),
)
register(
    "availability",
    Kind(
        check_availability,
        "fraction",
        {
            "estimator": ESTIMATOR_PARAM,
            "min_fraction": Param("number", required=True, lo=0.0, hi=1.0),
            "warn_fraction": Param("number", lo=0.0, hi=1.0),
        },
        Limit("min_fraction", "warn_fraction", upper=False),
        summary="fraction of sampling instants with a gradient",
    ),
)
register(
    "gradient_jump",
    Kind(
        check_gradient_jump,
        "permil",
        {
            "estimator": ESTIMATOR_PARAM,
            "max_permil": Param("number", required=True, lo=0.0),
            "warn_permil": Param("number", lo=0.0),
        },
        Limit("max_permil", "warn_permil", upper=True),
        summary="largest gradient change between consecutive samples",
    ),
)
register(
    "step_gradient",
    Kind(
        check_step_gradient,
        "permil",
        {
            "estimator": ESTIMATOR_PARAM,
            "statistic": Param("choice", "mean", choices=("mean", "max")),
            "step": Param("integer", lo=1),
            "max_permil": Param("number", required=True, lo=0.0),
            "warn_permil": Param("number", lo=0.0),
        },
        Limit("max_permil", "warn_permil", upper=True),
        needs_steps=True,
        summary="operator steps: measured vs expected gradient",
    ),
)
