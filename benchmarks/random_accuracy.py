"""Accuracy on randomised runs (``python -m benchmarks accuracy --random N --seed S``).

Each seed's scenario is drawn by :func:`benchmarks.random_runs.draw`, simulated, and
replayed through the bench's pipeline with the board's own calibration sheet, then scored
exactly as the shipped table is (:func:`benchmarks.accuracy.scores`: RMS, p99, max,
availability, > 1 permil wrong, 2-sigma coverage; the reference method against |truth|
beside the estimator). The estimator's targets are issue 26's, per run, by odometer class
(:data:`TARGETS`); a run that misses one says where in time it misses.

API (all seeds run in parallel worker processes; every result is JSON-ready)::

    random_scores(seeds, processes=2, **settings) -> list[dict]
        per seed: "scores" {method: {metric: value}}, "missed" [target keys], "where"
        (what the train was doing while it missed) and "spans" (the time spans withheld or
        wrong, merged, each with its context); ``settings`` override the calibration's
        settings (Config or EstimatorSettings fields, benchmarks.accuracy.with_settings).
    score_seed(seed, **settings) -> dict        the same for one seed, in this process
    replay_seed(seed, **settings) -> Replayed   the arrays of one run: truth (every column
        the emulator gives), estimator, sigma, reference, n, result flags, the Drawn run
    summarise(runs) -> dict                     median / worst decile / worst per method and
        metric, and how many runs meet each target
"""

from __future__ import annotations

import math
import multiprocessing
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.accuracy import METRICS, WRONG_PERMIL, _replay, scenario_config, scores
from benchmarks.accuracy import with_settings as _with_settings
from benchmarks.common import ROOT, Figure
from benchmarks.random_runs import REPORT_SEEDS, TUNING_SEEDS, Drawn, draw

DEFAULT_OUT = ROOT / "logs" / "random"
"""Where the drawn scenarios and their calibration sheets are written by default."""
FLAG_COLUMNS = ("odometer_suspect", "coasting", "excluded")
"""Result columns kept for the context of a miss (those the results have)."""
MOVING_MPS = 0.05
ACCEL_MPS2 = 0.05
MERGE_S = 1.0
"""Spans of one kind closer than this are one span."""
SPANS_KEPT = 6
"""Spans kept per run of the withheld (the longest) and the wrong (the worst) kind; half
as many of the others."""
LARGE_PERMIL = 0.8
"""Given with |error| beyond this (the p99 target): where an RMS or p99 miss comes from."""


@dataclass(frozen=True)
class Target:
    """One of issue 26's per-run targets for the estimator."""

    key: str
    metric: str
    text: str
    lo: float | None  # value must be >= lo
    hi: float | None  # value must be <= hi
    share: float  # of the runs that must meet it (1.0 = every run)
    classes: tuple[str, ...] = ("usable", "poor", "absent")  # odometer classes it applies to


TARGETS: tuple[Target, ...] = (
    Target("rms", "rms", "RMS <= 0.2 permil", None, 0.2, 0.95),
    Target("p99", "p99", "p99 <= 0.8 permil", None, 0.8, 0.95),
    Target("wrong", "wrong", "> 1 permil wrong <= 0.2 %", None, 0.2, 0.95),
    Target("wrong_never", "wrong", "> 1 permil wrong never > 0.5 %", None, 0.5, 1.0),
    Target(
        "avail", "avail", "availability >= 98 % (usable odometer)", 98.0, None, 0.95, ("usable",)
    ),
    Target(
        "avail_poor", "avail", "availability >= 92 % (poor odometer)", 92.0, None, 0.95, ("poor",)
    ),
    Target("cover", "cover", "2-sigma coverage 95-99 %", 95.0, 99.0, 0.95),
)
"""Issue 26's targets, applied per run; "share" is the part of the runs that must meet it
(95 %, or every run). No availability target applies without an odometer."""


def target_met(t: Target, value: float | None, odometer: str) -> bool | None:
    """True / False, or None where the target does not apply to the run's odometer class.
    A metric with no value (nothing given) misses, except without an odometer, where the
    estimator giving nothing claims nothing."""
    if odometer not in t.classes:
        return None
    if value is None:
        return odometer == "absent"
    return (t.lo is None or value >= t.lo) and (t.hi is None or value <= t.hi)


# ------------------------------------------------------------------------------ one run
@dataclass
class Replayed:
    """The arrays of one replayed random run (for debugging a miss)."""

    drawn: Drawn
    truth: np.ndarray  # the emulator's truth, one row per sampling instant, every column
    n: np.ndarray  # result rows: index into truth
    estimator: np.ndarray  # gradient_signed per row, NaN when withheld
    sigma: np.ndarray | None  # gradient_sigma per row
    reference: np.ndarray  # reference method's gradient per row, NaN when invalid
    flags: dict[str, np.ndarray]  # FLAG_COLUMNS per row (those the results have)
    sim: Any  # the Simulation (frames, odometer truth, scenario)
    config: Any  # the calibration sheet's config the run was replayed with

    @property
    def time_s(self) -> np.ndarray:
        return self.truth["time_s"]


def replay_seed(seed: int, **settings: Any) -> Replayed:
    """Draw, simulate and replay one seed with the board's calibration sheet."""
    from devices.emulator import simulate

    d = draw(seed)
    sim = simulate(d.scenario)
    config = _with_settings(scenario_config(d.scenario), settings)
    run = _replay(d.name, sim, config, FLAG_COLUMNS)
    return Replayed(
        drawn=d,
        truth=sim.truth,
        n=run.n,
        estimator=run.estimator,
        sigma=run.sigma,
        reference=run.reference,
        flags=run.columns,
        sim=sim,
        config=config,
    )


def run_scores(r: Replayed) -> dict[str, dict[str, float | None]]:
    truth = r.truth["gradient_permil"]
    return {
        "reference": scores(r.reference, r.n, truth, None, signed=False),
        "estimator": scores(r.estimator, r.n, truth, r.sigma, signed=True),
    }


def score_seed(seed: int, **settings: Any) -> dict[str, Any]:
    """One run's scores, the targets it misses and where (JSON-ready)."""
    t0 = time.perf_counter()
    r = replay_seed(seed, **settings)
    got = run_scores(r)
    est = got["estimator"]
    missed = [t.key for t in TARGETS if target_met(t, est[t.metric], r.drawn.odometer) is False]
    out: dict[str, Any] = {
        "seed": seed,
        "name": r.drawn.name,
        "summary": r.drawn.summary,
        "odometer": r.drawn.odometer,
        "samples": len(r.truth),
        "duration_s": r.drawn.data["duration_s"],
        "rate_hz": r.drawn.data["sample_rate_hz"],
        "scores": got,
        "missed": missed,
    }
    if missed:
        out["where"], out["spans"] = where_missed(r, missed)
    out["seconds"] = round(time.perf_counter() - t0, 2)
    return out


# ------------------------------------------------------------------------------ where
def _context(r: Replayed) -> dict[str, np.ndarray]:
    """Per sampling instant: what the train, the odometer and the board were doing."""
    from devices.emulator.world import gradient_slope

    sc = r.drawn.scenario
    tr = r.truth
    t = tr["time_s"]
    slope = gradient_slope(sc.track, sc.vertical_curve_m, tr["position_m"])
    fault = np.zeros(len(t), dtype=bool)
    dropout = np.zeros(len(t), dtype=bool)
    for f in sc.faults:
        inside = (t >= f.start_s) & (t < f.end_s)
        if f.target == "speed":
            dropout |= inside
        else:
            fault |= inside
    odo = r.sim.odometer
    wheel = np.zeros(len(t))
    if len(odo):
        k = np.clip(np.searchsorted(odo["time_s"], t, side="right") - 1, 0, len(odo) - 1)
        wheel = odo["wheel_error_mps"][k]
    return {
        "moving": np.abs(tr["speed_mps"]) > MOVING_MPS,
        "curve": slope != 0.0,
        "accel": np.abs(tr["accel_mps2"]) > ACCEL_MPS2,
        "fault": fault,
        "wheel": wheel != 0.0,
        "dropout": dropout,
        "slope": slope,
        "wheel_mps": wheel,
    }


def _per_instant(r: Replayed, values: np.ndarray | None, fill: float = np.nan) -> np.ndarray:
    out = np.full(len(r.truth), fill)
    if values is None:
        return out
    inside = (r.n >= 0) & (r.n < len(out))
    out[r.n[inside]] = values[inside]
    return out


def merged_spans(mask: np.ndarray, gap: int) -> list[tuple[int, int]]:
    """[start, end) index ranges of the True runs of ``mask``, runs closer than ``gap``
    samples merged."""
    idx = np.flatnonzero(mask)
    if not len(idx):
        return []
    breaks = np.flatnonzero(np.diff(idx) > gap + 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]]) + 1
    return list(zip(starts.tolist(), ends.tolist(), strict=True))


KINDS = {
    "withheld": "withheld (no value given)",
    "wrong": "given and > 1 permil wrong",
    "large": f"given and > {LARGE_PERMIL:g} permil off",
    "outside": "given and outside 2 sigma",
}
WHERE = {
    "moving": "moving",
    "curve": "on a vertical curve",
    "accel": "accelerating or braking",
    "fault": "in a channel fault",
    "wheel": "in wheel slide/slip",
    "dropout": "in a SPEED_REF dropout",
}
KINDS_OF = {
    "avail": ("withheld",),
    "avail_poor": ("withheld",),
    "wrong": ("wrong",),
    "wrong_never": ("wrong",),
    "rms": ("large",),
    "p99": ("large",),
    "cover": ("outside",),
}


def where_missed(
    r: Replayed, missed: Sequence[str]
) -> tuple[dict[str, dict[str, float]], list[dict[str, Any]]]:
    """For each kind of miss (withheld, wrong, large, outside 2 sigma) the share of the run
    it covers and what the truth was doing there (share moving, on a vertical curve,
    accelerating or braking, in a channel fault, wheel slide/slip, SPEED_REF dropout), and
    its merged time spans, each described."""
    ctx = _context(r)
    truth = r.truth["gradient_permil"]
    est = _per_instant(r, r.estimator)
    sig = _per_instant(r, r.sigma)
    given = np.isfinite(est)
    err = np.where(given, np.abs(est - truth), np.nan)
    with np.errstate(invalid="ignore"):
        masks = {
            "withheld": ~given,
            "wrong": given & (err > WRONG_PERMIL),
            "large": given & (err > LARGE_PERMIL),
            "outside": given & (err > 2.0 * sig),
        }
    flags = {k: _per_instant(r, v.astype(np.float64), 0.0) for k, v in r.flags.items()}
    kinds = sorted({k for m in missed for k in KINDS_OF.get(m, ())}, key=list(KINDS).index)
    if "wrong" in kinds and "large" in kinds:  # the wrong spans are the large ones' worst
        kinds.remove("large")
    if "outside" in kinds and np.count_nonzero(masks["outside"]) < 0.05 * np.count_nonzero(given):
        kinds.remove("outside")  # coverage above its range: sigma too wide, no span to show
    rate = float(r.drawn.data["sample_rate_hz"])
    where: dict[str, dict[str, float]] = {}
    spans: list[dict[str, Any]] = []
    for kind in kinds:
        m = masks[kind]
        count = int(m.sum())
        if not count:
            continue
        share = {c: _pct(ctx[c][m]) for c in WHERE}
        where[kind] = {"run": 100.0 * count / max(len(m), 1), **share}
        found = merged_spans(m, round(MERGE_S * rate))
        if kind == "withheld":
            found.sort(key=lambda s: s[0] - s[1])
        else:
            found.sort(key=lambda s: -float(np.nanmax(err[s[0] : s[1]])))
        where[kind]["spans"] = float(len(found))
        for i0, i1 in found[: SPANS_KEPT if kind in ("withheld", "wrong") else SPANS_KEPT // 2]:
            spans.append(_span(kind, i0, i1, r, ctx, err, sig, flags, m))
    return where, spans


def _pct(x: np.ndarray) -> float:
    return 100.0 * float(np.mean(x)) if len(x) else 0.0


def _span(
    kind: str,
    i0: int,
    i1: int,
    r: Replayed,
    ctx: dict[str, np.ndarray],
    err: np.ndarray,
    sig: np.ndarray,
    flags: dict[str, np.ndarray],
    mask: np.ndarray,
) -> dict[str, Any]:
    tr = r.truth
    t = tr["time_s"]
    sl = slice(i0, i1)
    out: dict[str, Any] = {
        "kind": kind,
        "t0": round(float(t[i0]), 3),
        "t1": round(float(t[i1 - 1]), 3),
        "samples": int(mask[sl].sum()),
    }
    if kind != "withheld" and np.isfinite(err[sl]).any():
        k = i0 + int(np.nanargmax(err[sl]))
        out["max_err_permil"] = round(float(err[k]), 3)
        out["sigma_permil"] = round(float(sig[k]), 3)
        out["at_s"] = round(float(t[k]), 3)
    out["what"] = describe(r, ctx, flags, i0, i1)
    return out


def describe(
    r: Replayed, ctx: dict[str, np.ndarray], flags: dict[str, np.ndarray], i0: int, i1: int
) -> str:
    """What the train, the track, the odometer, the board and the estimator did in
    [i0, i1): enough to know what to look at when replaying it."""
    tr = r.truth
    sl = slice(i0, i1)
    v = np.abs(tr["speed_mps"][sl])
    a = tr["accel_mps2"][sl]
    g = tr["gradient_permil"][sl]
    parts = []
    if v.max() <= MOVING_MPS:
        parts.append("standing")
    else:
        if v[0] <= MOVING_MPS < v[-1]:
            parts.append(f"departing 0 -> {v[-1]:.1f} m/s")
        elif v[-1] <= MOVING_MPS < v[0]:
            parts.append(f"stopping {v[0]:.1f} -> 0 m/s")
        else:
            parts.append(f"moving {v.min():.1f}-{v.max():.1f} m/s")
        standing = _pct(v <= MOVING_MPS)
        if standing >= 0.5:
            parts.append(f"standing {standing:.0f} % of it")
    if a.max() > ACCEL_MPS2:
        parts.append(f"accelerating up to {a.max():+.2f} m/s^2")
    if a.min() < -ACCEL_MPS2:
        parts.append(f"braking down to {a.min():+.2f} m/s^2")
    curve = ctx["curve"][sl]
    if curve.any():
        s = ctx["slope"][sl][curve]
        radius = 1000.0 / float(np.max(np.abs(s)))
        parts.append(f"vertical curve R {radius:.0f} m ({_pct(curve):.0f} % of it)")
    parts.append(
        f"grade {g[0]:+.1f}" + (f"..{g[-1]:+.1f}" if abs(g[-1] - g[0]) > 0.05 else "") + " permil"
    )
    t0, t1 = float(tr["time_s"][i0]), float(tr["time_s"][i1 - 1])
    hit = [f.label for f in r.drawn.scenario.faults if f.start_s <= t1 + 1.0 and f.end_s >= t0]
    if hit:
        parts.append("faults " + ", ".join(hit))
    wheel = ctx["wheel_mps"][sl]
    if (wheel != 0).any():
        parts.append(f"wheel slide/slip {wheel.min():+.2f}..{wheel.max():+.2f} m/s")
    for name, values in flags.items():
        on = values[sl]
        if name == "excluded":
            chans = sorted({int(c) for c in on if c})
            if chans:
                parts.append("excluded " + ", ".join(f"ch{c}" for c in chans))
        elif _pct(on != 0) >= 0.5:
            parts.append(f"{name} {_pct(on != 0):.0f} %")
    return "; ".join(parts)


# ------------------------------------------------------------------------------ many runs
def in_parallel(fn: Any, seeds: Iterable[int], processes: int = 2, **kwargs: Any) -> list[Any]:
    """``[fn(seed, **kwargs) for seed in seeds]`` over ``processes`` worker processes
    (spawned: each loads the estimator's compiled kernel from numba's cache); the longest
    runs start first so that the workers finish together. ``fn`` must be a module-level
    function (it is pickled)."""
    seeds = list(seeds)
    if processes <= 1 or len(seeds) <= 1:
        return [fn(s, **kwargs) for s in seeds]
    order = sorted(seeds, key=lambda s: -draw(s).samples)
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=processes, mp_context=ctx) as pool:
        futures = {s: pool.submit(fn, s, **kwargs) for s in order}
        return [futures[s].result() for s in seeds]


def random_scores(
    seeds: Iterable[int], processes: int = 2, **settings: Any
) -> list[dict[str, Any]]:
    """:func:`score_seed` of every seed, in seed order, over ``processes`` processes."""
    return in_parallel(score_seed, seeds, processes, **settings)


def distribution(values: Sequence[float | None], op: str) -> dict[str, float | None]:
    """Median, worst decile and worst of the runs' values (None ones left out): for a
    metric that must be small ("<=") the 90th percentile and the maximum, for one that
    must be large (">=") the 10th percentile and the minimum."""
    x = np.array([v for v in values if v is not None], dtype=np.float64)
    if not len(x):
        return {"median": None, "worst_decile": None, "worst": None, "runs": 0}
    small = op == "<="
    return {
        "median": float(np.median(x)),
        "worst_decile": float(np.percentile(x, 90 if small else 10)),
        "worst": float(x.max() if small else x.min()),
        "runs": len(x),
    }


AVAIL_BY_CLASS = {"avail_usable": "usable", "avail_poor": "poor"}
"""Extra rows of the distribution: availability over the runs of one odometer class."""


def _metric(key: str) -> tuple[str, str, str]:
    """(label, unit, op) of a distribution row."""
    if key in AVAIL_BY_CLASS:
        return f"availability, {AVAIL_BY_CLASS[key]} odometer", "%", ">="
    label, unit, op, _ = METRICS[key]
    return label, unit, op


def summarise(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The distribution of every metric per method, and per target how many of the runs
    it applies to meet it."""
    dist: dict[str, dict[str, Any]] = {}
    for method in ("reference", "estimator"):
        dist[method] = {
            metric: distribution([r["scores"][method][metric] for r in runs], op)
            for metric, (_, _, op, _) in METRICS.items()
        }
        for key, cls in AVAIL_BY_CLASS.items():
            of = [r["scores"][method]["avail"] for r in runs if r["odometer"] == cls]
            dist[method][key] = distribution(of, ">=")
    targets = {}
    for t in TARGETS:
        verdicts = [target_met(t, r["scores"]["estimator"][t.metric], r["odometer"]) for r in runs]
        applies = [v for v in verdicts if v is not None]
        targets[t.key] = {
            "text": t.text,
            "met": sum(applies),
            "runs": len(applies),
            "need": math.ceil(t.share * len(applies) - 1e-9),
            "share": t.share,
        }
    every = sum(1 for r in runs if not r["missed"])
    return {"distribution": dist, "targets": targets, "all_met": every, "runs": len(runs)}


def seed_set(first: int, n: int) -> str:
    """Which declared set seeds first .. first + n - 1 belong to."""
    last = first + n - 1
    if first >= REPORT_SEEDS.start:
        return "report set"
    if TUNING_SEEDS.start <= first and last < TUNING_SEEDS.stop:
        return "tuning set"
    return "neither the tuning nor the report set"


def write_scenarios(seeds: Iterable[int], out: Path) -> list[Path]:
    """Each seed's scenario (random-SEED.toml) and its board's calibration sheet
    (random-SEED-cal.toml) in ``out``."""
    from devices.emulator import calibration_toml

    out.mkdir(parents=True, exist_ok=True)
    written = []
    for s in seeds:
        d = draw(s)
        path = out / f"{d.name}.toml"
        path.write_text(d.toml())
        (out / f"{d.name}-cal.toml").write_text(calibration_toml(d.scenario))
        written.append(path)
    return written


# ------------------------------------------------------------------------------ figures
def measure(
    n: int = 50,
    seed: int = REPORT_SEEDS.start,
    processes: int = 2,
    scenarios_out: str | None = None,
    log: Any = None,
) -> list[Figure]:
    """Score seeds seed .. seed + n - 1 and give the figures (results.json)."""
    seeds = list(range(seed, seed + n))
    out = Path(scenarios_out) if scenarios_out else DEFAULT_OUT
    write_scenarios(seeds, out)
    if log is not None:
        log(f"random: {n} runs from seed {seed} ({seed_set(seed, n)}), scenarios in {out}")
    t0 = time.perf_counter()
    runs = random_scores(seeds, processes)
    elapsed = time.perf_counter() - t0
    return figures(runs, seed, elapsed, processes, str(out))


def figures(
    runs: list[dict[str, Any]], seed: int, elapsed: float, processes: int, out: str
) -> list[Figure]:
    s = summarise(runs)
    base = {"table": "random", "first_seed": seed, "n": len(runs)}
    figs = [
        Figure(
            "random_runs",
            f"random runs (seeds {seed}..{seed + len(runs) - 1}, {seed_set(seed, len(runs))})",
            float(len(runs)),
            "runs",
            detail=f"{elapsed:.0f} s on {processes} processes",
            extra=base
            | {
                "elapsed_s": round(elapsed, 1),
                "processes": processes,
                "scenarios_out": out,
                "all_met": s["all_met"],
                "runs": runs,
            },
        )
    ]
    for method, per in s["distribution"].items():
        for metric, d in per.items():
            label, unit, _ = _metric(metric)
            figs.append(
                Figure(
                    f"random_{method}_{metric}",
                    f"random: {method} {label} (median)",
                    d["median"],
                    unit,
                    detail="no sample given" if d["median"] is None else "",
                    extra=base | {"method": method, "metric": metric, **d},
                )
            )
    for key, t in s["targets"].items():
        figs.append(
            Figure(
                f"random_target_{key}",
                f"random: runs meeting {t['text']}",
                float(t["met"]),
                "runs",
                target=float(t["need"]),
                op=">=",
                detail=f"of {t['runs']} it applies to",
                extra=base | {"target": key, **t},
            )
        )
    return figs


def is_random(f: Figure) -> bool:
    return f.extra.get("table") == "random"


def _fmt(v: float | None, unit: str) -> str:
    if v is None:
        return "-"
    if unit == "%":
        return f"{v:.1f}" if v >= 1 or v == 0 else f"{v:.2f}"
    return f"{v:.3f}" if v < 10 else f"{v:.1f}"


def report_lines(figs: list[Figure]) -> dict[str, Any]:
    """The printable parts of the random figures: header, distribution rows, target rows
    and the misses (one block per run)."""
    head = next(f for f in figs if f.key == "random_runs")
    runs: list[dict[str, Any]] = head.extra["runs"]
    classes = {c: sum(r["odometer"] == c for r in runs) for c in ("usable", "poor", "absent")}
    title = (
        f"{head.label}: {len(runs)} runs ({classes['usable']} usable, {classes['poor']} poor, "
        f"{classes['absent']} absent odometer), {sum(r['samples'] for r in runs):,} samples, "
        f"{head.extra['elapsed_s']:.0f} s on {head.extra['processes']} processes; "
        f"{head.extra['all_met']} of {len(runs)} meet every target"
    )
    dist = {(f.extra["method"], f.extra["metric"]): f for f in figs if "metric" in f.extra}
    rows = []
    for metric in [*METRICS, *AVAIL_BY_CLASS]:
        label, unit, _ = _metric(metric)
        row = [f"{label} ({'permil' if unit == 'permil' else unit})"]
        for method in ("estimator", "reference"):
            f = dist.get((method, metric))
            e = f.extra if f else {}
            row += [_fmt(e.get(k), unit) for k in ("median", "worst_decile", "worst")]
        rows.append(row)
    targets = [
        [
            f.extra["text"],
            f"{f.extra['met']} of {f.extra['runs']}",
            f"{f.extra['need']}",
            f.status,
        ]
        for f in figs
        if "target" in f.extra
    ]
    return {"title": title, "rows": rows, "targets": targets, "misses": miss_blocks(head)}


DIST_HEADER = [
    "metric",
    "estimator median",
    "worst decile",
    "worst",
    "reference median",
    "worst decile",
    "worst",
]
TARGET_HEADER = ["issue 26 target (per run)", "runs meeting", "needed", ""]


def miss_blocks(head: Figure) -> list[list[str]]:
    """One block of lines per run that misses a target: what it missed, where, how to
    replay it."""
    out = []
    by_key = {t.key: t for t in TARGETS}
    folder = head.extra.get("scenarios_out", str(DEFAULT_OUT))
    for r in head.extra["runs"]:
        if not r["missed"]:
            continue
        est = r["scores"]["estimator"]
        miss = ", ".join(
            f"{by_key[k].text.split(' (')[0]} [{_fmt(est[by_key[k].metric], _unit(k))}]"
            for k in r["missed"]
        )
        lines = [f"seed {r['seed']} ({r['summary']}): misses {miss}"]
        for kind, w in r.get("where", {}).items():
            there = ", ".join(f"{w[k]:.0f} % {text}" for k, text in WHERE.items() if w[k] >= 0.5)
            lines.append(
                f"  {KINDS[kind]}: {w['run']:.2f} % of the run in {int(w['spans'])} spans"
                + (f"; there {there}" if there else "")
            )
        for s in r.get("spans", []):
            err = (
                f", worst {s['max_err_permil']:.2f} permil at sigma {s['sigma_permil']:.2f} "
                f"({s['at_s']:.2f} s)"
                if "max_err_permil" in s
                else ""
            )
            lines.append(
                f"    {s['kind']} {s['t0']:.2f}-{s['t1']:.2f} s ({s['samples']} samples{err}): "
                f"{s['what']}"
            )
        name = r["name"]
        lines.append(
            f"  replay: bench emulate {folder}/{name}.toml --out {name}.log "
            f"--calibration-out {name}-cal.toml && bench replay {name}.log --config "
            f"{name}-cal.toml --csv {name}.csv"
        )
        out.append(lines)
    return out


def _unit(key: str) -> str:
    return METRICS[next(t.metric for t in TARGETS if t.key == key)][1]


def print_random(figs: list[Figure], console: Any) -> None:
    from rich.table import Table

    rep = report_lines(figs)
    t = Table(title=rep["title"], title_justify="left")
    for i, col in enumerate(DIST_HEADER):
        t.add_column(col, justify="left" if i == 0 else "right")
    for row in rep["rows"]:
        t.add_row(*row)
    console.print(t)
    tt = Table(title="estimator targets (issue 26), per run", title_justify="left")
    for i, col in enumerate(TARGET_HEADER):
        tt.add_column(col, justify="left" if i == 0 else "right")
    for row in rep["targets"]:
        tt.add_row(*row)
    console.print(tt)
    console.print(
        "A target applies to the runs of its odometer class; one with no value (nothing "
        "given) misses, except without an odometer. 'needed' = 95 % of the runs it applies "
        "to (every run for 'never').",
        highlight=False,
    )
    for block in rep["misses"]:
        console.print("\n".join(block), highlight=False, markup=False)


def markdown(figs: list[Figure]) -> str:
    rep = report_lines(figs)
    lines = [rep["title"], ""]
    lines.append("| " + " | ".join(DIST_HEADER) + " |")
    lines.append("|---|" + "---:|" * (len(DIST_HEADER) - 1))
    lines += ["| " + " | ".join(r) + " |" for r in rep["rows"]]
    lines += ["", "| " + " | ".join(TARGET_HEADER[:3]) + " |", "|---|---:|---:|"]
    lines += ["| " + " | ".join(r[:3]) + " |" for r in rep["targets"]]
    lines += ["", *miss_table(figs), ""]
    return "\n".join(lines)


def miss_table(figs: list[Figure]) -> list[str]:
    """The runs that miss a target as Markdown rows: seed, what was drawn, the targets
    missed with their values, and per kind of miss its share of the run and its first
    span (the longest withheld, the worst wrong)."""
    head = next(f for f in figs if f.key == "random_runs")
    by_key = {t.key: t for t in TARGETS}
    rows = ["| seed | run | misses | where |", "|---:|---|---|---|"]
    for r in head.extra["runs"]:
        if not r["missed"]:
            continue
        est = r["scores"]["estimator"]
        miss = ", ".join(
            f"{by_key[k].metric} {_fmt(est[by_key[k].metric], _unit(k))}"
            for k in r["missed"]
            if k != "wrong_never" or "wrong" not in r["missed"]
        )
        where = []
        for kind, w in r.get("where", {}).items():
            first = next((sp for sp in r.get("spans", []) if sp["kind"] == kind), None)
            text = f"{kind} {w['run']:.2f} % in {int(w['spans'])} spans"
            if first is not None:
                err = (
                    f", {first['max_err_permil']:.2f} permil at sigma {first['sigma_permil']:.2f}"
                    if "max_err_permil" in first
                    else ""
                )
                text += f", e.g. {first['t0']:.1f}-{first['t1']:.1f} s{err}: {first['what']}"
            where.append(text)
        rows.append(f"| {r['seed']} | {r['summary']} | {miss} | " + "<br>".join(where) + " |")
    return rows
