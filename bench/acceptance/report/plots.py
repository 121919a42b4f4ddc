"""The report's plots (matplotlib, PNG): gradient against truth, slopes, votes, errors."""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench.acceptance.model import Measurement, RunData
from bench.acceptance.outcome import RunOutcome
from bench.records.events import EventKind
from devices.paths import staged

MAX_POINTS = 6000
"""Points per plotted line: longer series are reduced to a min/max envelope."""


def _envelope(x: np.ndarray, y: np.ndarray, max_points: int = MAX_POINTS) -> tuple:
    """Min/max per bin: a long series keeps its spikes when reduced for plotting."""
    n = len(x)
    if n <= max_points:
        return x, y
    bins = max_points // 2
    size = math.ceil(n / bins)
    pad = bins * size - n
    xp = np.concatenate([x, np.full(pad, x[-1])]).reshape(bins, size)
    yp = np.concatenate([y, np.full(pad, np.nan)]).reshape(bins, size)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN bins are expected
        lo, hi = np.nanmin(yp, axis=1), np.nanmax(yp, axis=1)
    xs = np.repeat(xp[:, 0], 2)
    ys = np.column_stack([lo, hi]).ravel()
    return xs, ys


def _shade(ax: Any, run: RunData) -> None:
    for f in run.faults:
        ax.axvspan(f.start_s, f.end_s, color="tab:red", alpha=0.08, lw=0)
    for s in run.steps:
        if s.answer != "skip":
            ax.axvspan(s.from_s, s.to_s, color="tab:green", alpha=0.10, lw=0)


def _figure(rows: int = 1, height: float = 3.2) -> tuple[Any, Any]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, height * rows), dpi=90, layout="constrained")
    axes = fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, axes


def plot_gradient(run: RunData, path: Path) -> None:
    fig, (ax,) = _figure()
    t = run.time_s
    r = run.results
    ax.plot(*_envelope(t, r["gradient"]), color="tab:blue", lw=0.8, label="reference (device)")
    if np.isfinite(r["gradient_signed"]).any():
        ax.plot(
            *_envelope(t, r["gradient_signed"]), color="tab:orange", lw=0.8, label="signed (bench)"
        )
    if "gradient_smoothed" in (r.dtype.names or ()) and np.isfinite(r["gradient_smoothed"]).any():
        ax.plot(  # a plan with smoothed checks (bench.acceptance.smoothing)
            *_envelope(t, r["gradient_smoothed"]), color="tab:green", lw=0.8, label="smoothed"
        )
    if run.truth_gradient is not None:
        tt = np.arange(len(run.truth_gradient)) / run.rate_hz
        ax.plot(*_envelope(tt, run.truth_gradient), "k--", lw=1.2, label="truth", zorder=3)
        if (run.truth_gradient < 0).any():
            ax.plot(
                *_envelope(tt, np.abs(run.truth_gradient)),
                color="grey",
                lw=1.0,
                ls=":",
                label="|truth|",
                zorder=3,
            )
    for s in run.steps:
        if s.answer != "skip":
            ax.hlines(s.expected_permil, s.from_s, s.to_s, color="tab:green", lw=2)
    _shade(ax, run)
    ax.set_ylabel("gradient, permil")
    ax.set_xlabel("run time, s")
    ax.set_title("gradient vs truth (red: fault windows, green: step windows)")
    ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)
    fig.savefig(path)


def plot_slopes(run: RunData, path: Path) -> None:
    fig, (ax,) = _figure()
    t = run.time_s
    for k, (name, color) in enumerate(
        (("s1 = g12", "tab:blue"), ("s2 = g23", "tab:orange"), ("s3 = g13", "tab:green"))
    ):
        ax.plot(*_envelope(t, run.results["slopes"][:, k]), lw=0.8, color=color, label=name)
    _shade(ax, run)
    ax.set_ylabel("pair gradient, permil")
    ax.set_xlabel("run time, s")
    ax.set_title("pair values (reference method, unsigned)")
    ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)
    fig.savefig(path)


def _timeline(run: RunData, rows: list[np.ndarray], bins: int = 1500) -> tuple[np.ndarray, float]:
    """Boolean per-sample rows -> (rows, bins) fraction of samples set per time bin."""
    span = max(run.n_samples, 1)
    bins = min(bins, span)
    k = np.clip(run.k, 0, span - 1)
    idx = (k * bins) // span
    out = np.zeros((len(rows), bins))
    total = np.bincount(idx, minlength=bins).astype(float)
    for i, row in enumerate(rows):
        out[i] = np.bincount(idx, weights=row.astype(float), minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(total > 0, out / np.maximum(total, 1), np.nan)
    return out, span / run.rate_hz


def plot_votes(run: RunData, path: Path) -> None:
    r = run.results
    rows = [~r["votes"][:, 0], ~r["votes"][:, 1], ~r["votes"][:, 2], ~r["valid"], r["degraded"]]
    rows += [r["excluded"] == c for c in (1, 2, 3)]
    rows += [~r["present"][:, c] for c in range(3)]
    labels = ["v1 failed", "v2 failed", "v3 failed", "invalid", "degraded"]
    labels += [f"ch{c} excluded" for c in (1, 2, 3)] + [f"ch{c} missing" for c in (1, 2, 3)]
    grid, end_s = _timeline(run, rows)
    fig, (ax,) = _figure(height=3.6)
    cmap = _cmap()
    ax.imshow(
        grid,
        aspect="auto",
        interpolation="nearest",
        extent=(0, end_s, len(rows) - 0.5, -0.5),
        cmap=cmap,
        vmin=0,
        vmax=1,
    )
    ax.set_yticks(range(len(rows)), labels, fontsize="small")
    ax.set_xlabel("run time, s")
    ax.set_title("vote timeline (white: never, red: every sample of the bin)")
    for f in run.faults:
        ax.axvline(f.start_s, color="black", lw=0.6, ls=":")
    fig.savefig(path)


def _cmap() -> Any:
    from matplotlib.colors import LinearSegmentedColormap

    cmap = LinearSegmentedColormap.from_list("fails", ["#ffffff", "#f4a582", "#b2182b"])
    return cmap.with_extremes(bad="#dddddd")


_EVENT_ROWS = (
    "GAP",
    "CRC_ERROR",
    "STATUS_FLAG",
    "COUNTER_JUMP",
    "DUPLICATE",
    "LATE",
    "SAMPLES_LOST",
    "LINK_ERROR",
    "EXCLUDED",
)


def plot_errors(run: RunData, measurements: list[Measurement], path: Path) -> None:
    """Top: gradient error against truth (or against each step's expected value) with the
    plan's gradient limits; bottom: the bench's fault and link events over time."""
    fig, (ax, ax2) = _figure(rows=2)
    t = run.time_s
    r = run.results
    plotted = False
    if run.truth_gradient is not None:
        truth = run.truth_at()
        e_ref = r["gradient"] - np.abs(truth)
        ax.plot(*_envelope(t, e_ref), lw=0.8, color="tab:blue", label="reference - |truth|")
        if np.isfinite(r["gradient_signed"]).any():
            e_sig = r["gradient_signed"] - truth
            ax.plot(*_envelope(t, e_sig), lw=0.8, color="tab:orange", label="signed - truth")
        if "gradient_smoothed" in (r.dtype.names or ()):
            e_sm = r["gradient_smoothed"] - truth
            if np.isfinite(e_sm).any():
                ax.plot(*_envelope(t, e_sm), lw=0.8, color="tab:purple", label="smoothed - truth")
        plotted = True
    for s in run.steps:
        if s.answer == "skip":
            continue
        sel = (t >= s.from_s) & (t < s.to_s)
        ax.plot(t[sel], r["gradient"][sel] - abs(s.expected_permil), lw=0.8, color="tab:green")
        plotted = True
    for m in measurements:
        if m.kind not in ("gradient_error", "step_gradient") or "max" not in m.limits:
            continue
        lo = 0.0 if m.from_s is None else m.from_s
        hi = run.n_samples / run.rate_hz if m.to_s is None else m.to_s
        for sign in (1, -1):
            ax.hlines(sign * m.limits["max"], lo, hi, color="tab:red", lw=1, ls="--")
    ax.axhline(0, color="black", lw=0.5)
    ax.set_ylabel("error, permil")
    title = "gradient error (dashed: limits of the gradient checks)"
    lim = _error_range(ax, measurements)
    if lim is not None:
        ax.set_ylim(-lim, lim)
        title += f"; clipped at +/-{lim:.3g}"
    ax.set_title(title)
    if plotted:
        ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)
    _shade(ax, run)
    ev = run.events
    ks = run.event_k(ev) if len(ev) else np.zeros(0, np.int64)
    for i, name in enumerate(_EVENT_ROWS):
        sel = ev["kind"] == int(EventKind[name])
        if sel.any():
            ax2.plot(ks[sel] / run.rate_hz, np.full(int(sel.sum()), i), "|", ms=8, color="tab:red")
    ax2.set_yticks(range(len(_EVENT_ROWS)), _EVENT_ROWS, fontsize="small")
    ax2.set_ylim(-0.5, len(_EVENT_ROWS) - 0.5)
    ax2.set_xlabel("run time, s")
    ax2.set_title("fault and link events")
    ax2.grid(alpha=0.3)
    fig.savefig(path)


def _error_range(ax: Any, measurements: list[Measurement]) -> float | None:
    """A y range that shows the limits and the bulk of the errors: a few transients of
    100 permil would otherwise flatten everything a 0.5 permil limit is about."""
    ys = [np.abs(line.get_ydata()) for line in ax.get_lines()]
    ys = [y[np.isfinite(y)] for y in ys if len(y)]
    values = np.concatenate(ys) if ys else np.zeros(0)
    if len(values) == 0:
        return None
    limits = [
        m.limits["max"]
        for m in measurements
        if m.kind in ("gradient_error", "step_gradient") and "max" in m.limits
    ]
    lim = max(2.0 * float(np.percentile(values, 99.5)), 2.0 * max(limits, default=0.0), 0.05)
    return lim if lim < float(values.max()) else None


PLOT_NAMES = ("gradient", "slopes", "votes", "errors")
"""The plots of a report, each ``NAME.png`` in the run's folder."""


def write_plots(outcome: RunOutcome, out: Path) -> dict[str, str]:
    """Every plot into ``out``, each renamed into place once drawn; name -> file name."""
    run = outcome.run
    if run is None or len(run.results) == 0:
        return {}
    jobs: dict[str, Callable[[Path], None]] = {
        "gradient": lambda p: plot_gradient(run, p),
        "slopes": lambda p: plot_slopes(run, p),
        "votes": lambda p: plot_votes(run, p),
        "errors": lambda p: plot_errors(run, outcome.measurements, p),
    }
    files = {}
    for name in PLOT_NAMES:
        p = out / f"{name}.png"
        with staged(p) as tmp:
            jobs[name](tmp)
        files[name] = p.name
    return files
