"""Accuracy on realistic emulated runs: the reference method and the bench's estimator against
the emulator's truth, per shipped realistic scenario.

Each scenario is simulated (devices.emulator), and its CAN frames go through the bench's own
replay pipeline (:func:`bench.replay.run.run_steps` over a
:class:`bench.pipeline.steps.Pipeline`, in replay-sized batches: the code ``bench replay``
runs) with the board's as-built calibration (:func:`devices.emulator.calibration_toml`).
Only the few result columns needed are kept per step. Per method:

* samples: every sampling instant of the run (the truth's rows), lost or not;
* given: the method gives a value (reference: ``valid``; estimator: ``gradient_signed``
  finite and not withheld);
* error: reference ``gradient - |truth|`` (it has no sign), estimator ``gradient_signed -
  truth``, per mille; RMS, p99 and max of |error| over the given samples;
* availability: given / samples; wrong: given and |error| > 1 per mille, / samples;
* 2-sigma coverage (estimator): |error| <= 2 ``gradient_sigma`` / given, when the results
  have that column.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from benchmarks.common import Figure

SCENARIOS: tuple[str, ...] = (
    "metro_run",
    "metro_vibration",
    "grade_stop",
    "accel_steps",
    "channel_faults",
    "wheel_slide",
    "speed_dropout",
    "demo",
)
"""The shipped realistic scenarios (devices/scenarios/), in table order."""

POOR_ODOMETER = frozenset({"wheel_slide", "speed_dropout", "demo"})
"""Scenarios whose odometer is poor or absent for a while: only 'wrong' has a target there."""

WRONG_PERMIL = 1.0
BATCH_FRAMES = 65536

# metric -> (label, unit, op, target for the estimator with a usable odometer)
METRICS: dict[str, tuple[str, str, str, float | None]] = {
    "rms": ("RMS", "permil", "<=", 0.3),
    "p99": ("p99", "permil", "<=", 1.0),
    "max": ("max", "permil", "<=", None),
    "avail": ("availability", "%", ">=", 97.0),
    "wrong": ("> 1 permil wrong", "%", "<=", 0.5),
    "cover": ("within 2 sigma", "%", ">=", 95.0),
}
METHODS = {
    "reference": "reference (vs |truth|)",
    "estimator": "estimator (signed)",
    "told": "estimator, curves told",
}
TOLD = ("metro_vibration",)
"""Scenarios also scored with the filter told each vertical curve's start and end (its
bound: what a perfect curve detector would give, :func:`replay_told`)."""


@dataclass
class Run:
    """What the accuracy figures need of one emulated run."""

    name: str
    description: str
    truth_permil: np.ndarray  # per sampling instant
    n: np.ndarray  # result rows: sample index into truth_permil
    reference: np.ndarray  # reference gradient, NaN when invalid
    estimator: np.ndarray  # gradient_signed, NaN when unavailable
    sigma: np.ndarray | None  # gradient_sigma, when the results have it
    columns: dict[str, np.ndarray] = field(default_factory=dict)  # extra result columns asked for


def scenario_config(sc: Any) -> Any:
    """The bench config for the virtual board as built (its calibration sheet)."""
    from bench.config import config_from_dict
    from devices.emulator import calibration_toml

    return config_from_dict(tomllib.loads(calibration_toml(sc)), source=f"{sc.source} calibration")


def emulate(name: str) -> tuple[Any, Any]:
    """(simulation, config) of a built-in scenario: ``sim.frames``, ``sim.truth``."""
    from devices.emulator import load_scenario, simulate

    sc = load_scenario(name)
    return simulate(sc), scenario_config(sc)


def _batches(frames: np.ndarray) -> Iterator[Any]:
    from devices.base import SourceBatch

    for i in range(0, len(frames), BATCH_FRAMES):
        yield SourceBatch(frames[i : i + BATCH_FRAMES])


def curve_changes(truth: np.ndarray, g: float) -> list[tuple[float, float]]:
    """(time, step of k) where the truth's rate per metre of g sin(alpha) changes: each
    vertical curve's start and end."""
    s = g * np.sin(np.arctan(truth["gradient_permil"] / 1000.0))
    dx = np.gradient(truth["position_m"])
    k = np.round(np.where(dx > 1e-6, np.gradient(s) / np.maximum(dx, 1e-9), 0.0), 4)
    out: list[tuple[float, float]] = []
    for i in np.flatnonzero(np.abs(np.diff(k)) > 5e-4).tolist():
        t = float(truth["time_s"][i])
        if not out or t - out[-1][0] > 0.5:
            out.append((t, float(k[min(i + 3, len(k) - 1)] - k[max(i - 3, 0)])))
    return out


def replay_told(name: str) -> Run:
    """The run replayed with the filter told each curve's start and end as it comes: its
    curve detector off, k's variance raised by the true step (1 sigma) at the true
    instant. Nothing detects better than that, so its availability bounds what any curve
    detector can give on this run with the filter's models of w and of the odometer."""
    from bench.fusion import estimator as estimator_module
    from bench.fusion import joint_layout as jl
    from bench.fusion.joint import FilterOutput, JointFilter

    sim, config = emulate(name)
    changes = curve_changes(sim.truth, config.g)

    class Told(JointFilter):
        def __init__(self, *a: Any, **k: Any) -> None:
            self.next = 0  # the next change to tell
            super().__init__(*a, **k)
            self.p[jl.P_WDET_SIGMA] = 1e9  # the detector never fires nor hedges

        def push(self, b, u, w, mask, residual, latched, frames):
            # cut the push at each change it holds: (first sample on or off the curve, step)
            cuts: list[tuple[int, float]] = []
            while self.next < len(changes) and len(b) and changes[self.next][0] <= b[-1]:
                t, dk = changes[self.next]
                cuts.append((int(np.searchsorted(b, t)), dk))
                self.next += 1
            fa = frames[0] if frames is not None else np.zeros(0, np.int64)
            outs, lo = [], 0
            for hi, dk in [*cuts, (len(b), 0.0)]:
                sel = (fa >= lo) & (fa < hi)
                fr = None if frames is None else (fa[sel] - lo, *(f[sel] for f in frames[1:]))
                args = (b, u, w, mask, residual, latched)
                outs.append(super().push(*(x[lo:hi] for x in args), fr))
                self.cov[jl.IK, jl.IK] += dk * dk
                lo = hi
            return FilterOutput(
                *(np.concatenate([getattr(o, f.name) for o in outs]) for f in fields(FilterOutput))
            )

    # the estimator module's own name for the filter class, patched for this one replay
    real = estimator_module.JointFilter  # type: ignore[attr-defined]  # imported there, not re-exported
    estimator_module.JointFilter = Told  # type: ignore[attr-defined]  # the same name
    try:
        return _replay(name, sim, config)
    finally:
        estimator_module.JointFilter = real  # type: ignore[attr-defined]  # the same name


def with_settings(config: Any, settings: dict[str, Any]) -> Any:
    """``config`` with some settings overridden: a field of the config itself
    (``gradient_sigma_limit_permil``) or of its estimator settings (``curve_rewind_s``)."""
    if not settings:
        return config
    top = {f.name for f in fields(config)} - {"estimator", "channels"}
    est = {f.name for f in fields(config.estimator)}
    unknown = sorted(set(settings) - top - est)
    if unknown:
        raise TypeError(f"unknown setting {unknown[0]!r} (not in Config or EstimatorSettings)")
    estimator = replace(config.estimator, **{k: v for k, v in settings.items() if k in est})
    return replace(config, estimator=estimator, **{k: v for k, v in settings.items() if k in top})


def replay_run(name: str, **settings: Any) -> Run:
    """Emulate a scenario and replay its frames through the bench's pipeline; ``settings``
    override the calibration's settings (``curve_rewind_s=0.0``, ...: :func:`with_settings`)."""
    sim, config = emulate(name)
    return _replay(name, sim, with_settings(config, settings))


def _replay(name: str, sim: Any, config: Any, extra: Sequence[str] = ()) -> Run:
    """Replay ``sim``'s frames; ``extra`` result columns are kept too (those the results have)."""
    from bench.pipeline.steps import Pipeline
    from bench.replay.run import run_steps

    counter0 = int(sim.truth["counter"][0]) if len(sim.truth) else 0
    cols: dict[str, list[np.ndarray]] = {"n": [], "gradient": [], "signed": [], "sigma": []}
    more: dict[str, list[np.ndarray]] = {}
    has_sigma = False
    for step in run_steps(Pipeline(config), _batches(sim.frames)):
        res = step.results
        if not len(res):
            continue
        names = res.dtype.names or ()
        has_sigma = has_sigma or "gradient_sigma" in names
        cols["n"].append(res["n"] - counter0)
        cols["gradient"].append(np.where(res["valid"], res["gradient"], np.nan))
        cols["signed"].append(res["gradient_signed"].copy())
        if "gradient_sigma" in names:
            cols["sigma"].append(res["gradient_sigma"].copy())
        for col in extra:
            if col in names:
                more.setdefault(col, []).append(res[col].copy())
    joined = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    return Run(
        name=name,
        description=sim.scenario.description,
        truth_permil=sim.truth["gradient_permil"].copy(),
        n=joined["n"].astype(np.int64),
        reference=joined["gradient"],
        estimator=joined["signed"],
        sigma=joined["sigma"] if has_sigma else None,
        columns={k: np.concatenate(v) for k, v in more.items()},
    )


def scores(
    value: np.ndarray, n: np.ndarray, truth: np.ndarray, sigma: np.ndarray | None, signed: bool
) -> dict[str, float | None]:
    """The metrics of one method (module docstring) over every sampling instant of a run."""
    total = len(truth)
    inside = (n >= 0) & (n < total)
    value, n = value[inside], n[inside]
    given = np.isfinite(value)
    want = truth[n] if signed else np.abs(truth[n])
    err = np.abs(value[given] - want[given])
    k = len(err)
    out: dict[str, float | None] = {
        "rms": float(np.sqrt(np.mean(err**2))) if k else None,
        "p99": float(np.percentile(err, 99)) if k else None,
        "max": float(err.max()) if k else None,
        "avail": 100.0 * k / total if total else None,
        "wrong": 100.0 * float(np.count_nonzero(err > WRONG_PERMIL)) / total if total else None,
        "cover": None,
    }
    if sigma is not None and k:
        s = sigma[inside][given]
        out["cover"] = 100.0 * float(np.count_nonzero(err <= 2.0 * s)) / k
    return out


def _target(name: str, method: str, metric: str) -> float | None:
    if method != "estimator":
        return None
    target = METRICS[metric][3]
    if name in POOR_ODOMETER and metric != "wrong":
        return None
    return target


def figures_for(run: Run, told: Run | None = None) -> list[Figure]:
    out = []
    methods = [
        ("reference", run.reference, run.n, False, None),
        ("estimator", run.estimator, run.n, True, run.sigma),
    ]
    if told is not None:
        methods.append(("told", told.estimator, told.n, True, told.sigma))
    for method, values, n, signed, sigma in methods:
        got = scores(values, n, run.truth_permil, sigma, signed)
        for metric, (label, unit, op, _) in METRICS.items():
            if metric == "cover" and sigma is None:
                continue  # no sigma, no coverage: the table prints '-'
            value = got[metric]
            detail = "" if value is not None else "no sample given"
            out.append(
                Figure(
                    f"accuracy_{run.name}_{method}_{metric}",
                    f"{run.name}: {method} {label}",
                    value,
                    unit,
                    target=_target(run.name, method, metric),
                    op=op,
                    detail=detail,
                    extra={
                        "table": "accuracy",
                        "scenario": run.name,
                        "description": run.description,
                        "method": method,
                        "metric": metric,
                    },
                )
            )
    return out


def measure(scenarios: list[str] | None = None, log: Any = None) -> list[Figure]:
    out: list[Figure] = []
    for name in scenarios or SCENARIOS:
        if log is not None:
            log(f"accuracy: {name}")
        out += figures_for(replay_run(name), replay_told(name) if name in TOLD else None)
    return out


# ------------------------------------------------------------------------------- tables
def is_accuracy(f: Figure) -> bool:
    return f.extra.get("table") == "accuracy"


def cell(f: Figure | None) -> str:
    """A table cell: the value (3 significant places), '-' when there is none, and a mark
    when it misses its target."""
    if f is None or f.value is None or (isinstance(f.value, float) and math.isnan(f.value)):
        return "-"
    v = f.value
    text = f"{v:.1f}" if f.unit == "%" else (f"{v:.3f}" if v < 10 else f"{v:.1f}")
    return text + (" ✗" if f.status == "MISS" else "")


def tables(figures: list[Figure]) -> list[tuple[str, str, list[list[str]]]]:
    """(scenario, description, rows) per scenario: one row per method, one column per metric."""
    by: dict[str, dict[tuple[str, str], Figure]] = {}
    desc: dict[str, str] = {}
    for f in figures:
        if not is_accuracy(f):
            continue
        s = f.extra["scenario"]
        by.setdefault(s, {})[(f.extra["method"], f.extra["metric"])] = f
        desc[s] = f.extra.get("description", "")
    out = []
    for s, cells in by.items():
        rows = [
            [label] + [cell(cells.get((method, metric))) for metric in METRICS]
            for method, label in METHODS.items()
            if any(m == method for m, _ in cells)
        ]
        out.append((s, desc[s], rows))
    return out


def header() -> list[str]:
    return ["method"] + [
        f"{label} ({'‰' if unit == 'permil' else unit})" for label, unit, _, _ in METRICS.values()
    ]


def targets_line() -> str:
    parts = [
        f"{label} {op} {t:g}{'‰' if unit == 'permil' else ' %'}"
        for label, unit, op, t in METRICS.values()
        if t is not None
    ]
    return (
        "✗ = misses the estimator's target (" + ", ".join(parts) + "; with a poor or absent "
        f"odometer ({', '.join(sorted(POOR_ODOMETER))}) only '> 1 permil wrong')"
    )


def print_tables(figures: list[Figure], console: Any) -> None:
    from rich.table import Table

    for s, desc, rows in tables(figures):
        t = Table(title=f"accuracy: {s} — {desc}", title_justify="left")
        for i, col in enumerate(header()):
            t.add_column(col, justify="left" if i == 0 else "right")
        for r in rows:
            t.add_row(*r)
        console.print(t)
    console.print(targets_line(), highlight=False)


def markdown(figures: list[Figure]) -> str:
    lines = []
    for s, desc, rows in tables(figures):
        lines += [f"**{s}** — {desc}", ""]
        cols = header()
        lines.append("| " + " | ".join(cols) + " |")
        lines.append("|---|" + "---:|" * (len(cols) - 1))
        lines += ["| " + " | ".join(c.replace("|", "\\|") for c in r) + " |" for r in rows]
        lines.append("")
    if lines:
        lines.append(targets_line())
        lines.append("")
    return "\n".join(lines)
