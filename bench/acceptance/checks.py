"""Acceptance checks: one function per kind, each turning a finished run into a Measurement.

Checks are pure functions of :class:`RunData` (arrays and counts, no files, no emulator
objects), so a run and the replay of its MCAP log give the same measurements, and each
kind can be tested against hand-made arrays. Every limit is data from the plan; a check
never decides a limit itself.

Time in a plan is *run time*: sample k of the run (k = 0 for the first sampling instant)
is at k / sample_rate seconds, on the board's clock, not the PC's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.records.events import EventKind

VERDICTS = ("pass", "warn", "fail", "error", "skip")

FLAG_SOURCES = (
    "GAP",
    "CRC_ERROR",
    "STATUS_FLAG",
    "COUNTER_JUMP",
    "DUPLICATE",
    "LATE",
    "EXCLUDED",
    "VOTE_FAIL",
)
"""What may flag a channel for ``fault_detected`` (see :func:`channel_flags`)."""

VOTE_SIGNATURE = {1: (0, 1), 2: (1, 2), 3: (0, 2)}
"""Votes (0-based v1..v3) that fail when channel c alone is bad: the two votes comparing the
one slope value that does not use c with the two that do (ch1 -> v1, v2; ch2 -> v2, v3;
ch3 -> v1, v3)."""

ESTIMATORS = {
    # name: (result column, compare with |truth|: the column has no sign)
    "reference": ("gradient", True),
    "signed": ("gradient_signed", False),
    "magnitude": ("gradient_ls", True),
}


# --------------------------------------------------------------------------- data model


@dataclass(frozen=True, slots=True)
class FaultInfo:
    """One injected fault as the checks need it (from the emulator's record of effects)."""

    index: int  # 1-based position in the scenario's [[faults]]
    kind: str
    channels: tuple[int, ...]  # ADC channels it acts on (empty: status, speed or uart faults)
    label: str
    start_s: float
    end_s: float
    onset_k: int | None  # first sample it acted on; None when it had no effect on samples
    affected: int  # frames/packets it changed, added, moved or removed


@dataclass(frozen=True, slots=True)
class StepWindow:
    """An operator step as it was run: what was expected and which run time it measured."""

    index: int  # 1-based
    prompt: str
    expected_permil: float
    start_s: float  # run time the step was confirmed
    from_s: float  # measuring window (after settling)
    to_s: float
    answer: str = "ok"  # ok | skip
    note: str = ""


@dataclass
class RunData:
    """Everything a check may measure. Arrays are in sample order."""

    results: np.ndarray  # RESULT_DTYPE
    events: np.ndarray  # EVENT_DTYPE
    rate_hz: float
    n_ref: int  # result n of sample k = 0
    truth_gradient: np.ndarray | None = None  # per truth sample k (None: no emulator truth)
    faults: tuple[FaultInfo, ...] = ()
    frames_sent: int | None = None
    frames_received: int = 0
    frames_logged: int | None = None
    frames_dropped: int = 0
    steps: tuple[StepWindow, ...] = ()
    latency_ms: tuple[float, float] | None = None  # p50, p99 (live runs only)
    mode: str = "emulated"
    link: str = "can"
    _k: np.ndarray | None = field(default=None, repr=False)

    @property
    def k(self) -> np.ndarray:
        """Sample index of each result (0 = first sampling instant of the run)."""
        if self._k is None:
            self._k = self.results["n"].astype(np.int64) - self.n_ref
        return self._k

    @property
    def time_s(self) -> np.ndarray:
        return self.k / self.rate_hz

    @property
    def n_samples(self) -> int:
        """Sampling instants the run spans (truth length when there is truth)."""
        if self.truth_gradient is not None:
            return len(self.truth_gradient)
        return int(self.k.max()) + 1 if len(self.k) else 0

    def truth_at(self) -> np.ndarray:
        """Truth gradient per result (NaN where the result has no truth sample)."""
        out = np.full(len(self.results), np.nan)
        if self.truth_gradient is None:
            return out
        k = self.k
        ok = (k >= 0) & (k < len(self.truth_gradient))
        out[ok] = self.truth_gradient[k[ok]]
        return out

    def event_k(self, events: np.ndarray) -> np.ndarray:
        """Sample index of events: their n where they carry one, else the result received
        nearest in time (CRC errors and link errors name no sample)."""
        k = events["n"].astype(np.int64) - self.n_ref
        no_n = events["n"] < 0
        if no_n.any():
            if len(self.results) == 0:
                k[no_n] = -1
            else:
                t = self.results["t"]
                order = np.argsort(t, kind="stable")
                ts = t[order]
                pos = np.searchsorted(ts, events["t"][no_n])
                lo = np.clip(pos - 1, 0, len(ts) - 1)
                hi = np.clip(pos, 0, len(ts) - 1)
                ev_t = events["t"][no_n]
                pick = np.where(np.abs(ts[hi] - ev_t) < np.abs(ev_t - ts[lo]), hi, lo)
                k[no_n] = self.k[order[pick]]
        return k


@dataclass
class Measurement:
    """The outcome of one check: what was measured, against which limits, and the verdict."""

    name: str
    kind: str
    value: float | None
    unit: str
    limits: dict[str, float]
    verdict: str
    detail: str
    from_s: float | None = None
    to_s: float | None = None
    margin: float | None = None  # distance to the fail limit in `unit`; negative = failed
    expect: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "value": _json_num(self.value),
            "unit": self.unit,
            "limits": self.limits,
            "verdict": self.verdict,
            "detail": self.detail,
            "window_s": [self.from_s, self.to_s],
            "margin": _json_num(self.margin),
            "expect": self.expect,
            "extra": _jsonable(self.extra),
        }


def _json_num(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        return _json_num(obj)
    return obj


# --------------------------------------------------------------------------- check specs


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


# --------------------------------------------------------------------------- helpers


def _window(spec: CheckSpec, run: RunData) -> np.ndarray:
    """Results inside the check's run-time window."""
    t = run.time_s
    sel = run.k >= 0
    if spec.from_s is not None:
        sel &= t >= spec.from_s - 1e-9
    if spec.to_s is not None:
        sel &= t < spec.to_s - 1e-9
    return sel


def _expected_samples(spec: CheckSpec, run: RunData) -> int:
    """Sampling instants the window spans (lost ones included)."""
    total = run.n_samples
    lo = 0 if spec.from_s is None else math.ceil(spec.from_s * run.rate_hz - 1e-6)
    hi = total if spec.to_s is None else min(total, math.ceil(spec.to_s * run.rate_hz - 1e-6))
    return max(0, hi - max(lo, 0))


def _fmt(v: float | None, unit: str) -> str:
    if v is None or not math.isfinite(v):
        return "n/a"
    if unit == "fraction":
        return f"{v:.4%}"
    return f"{v:.4g} {unit}"


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
                f"{_fmt(value, unit)} {cmp_fail} limit {_fmt(limit, unit)} "
                f"(by {_fmt(-margin, unit)})"
            )
        elif warn is not None and ((value > warn) if lim.upper else (value < warn)):
            verdict = "warn"
            text = (
                f"{_fmt(value, unit)} within limit {_fmt(limit, unit)} but past the warning "
                f"limit {_fmt(warn, unit)} (margin {_fmt(margin, unit)})"
            )
        else:
            verdict = "pass"
            text = f"{_fmt(value, unit)} within limit {_fmt(limit, unit)}"
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


def _gradient(spec: CheckSpec, run: RunData) -> tuple[np.ndarray, bool, str]:
    column, unsigned = ESTIMATORS[spec.get("estimator")]
    return run.results[column].astype(np.float64), unsigned, column


# --------------------------------------------------------------------------- the kinds


def check_gradient_error(spec: CheckSpec, run: RunData) -> Measurement:
    """|gradient - truth| per sample over the window, reduced by `statistic`.

    The reference method and the least-squares magnitude carry no sign (METHOD.md section
    4), so by default (`truth = "auto"`) they are compared with |truth| and the signed
    estimator with truth itself; `truth = "signed"` holds an unsigned method to the sign.
    Samples without a gradient are not errors here: availability measures them."""
    if run.truth_gradient is None:
        return not_measured(spec, "error", "no emulator truth in this run (real board)")
    grad, unsigned, column = _gradient(spec, run)
    truth = run.truth_at()
    mode = spec.get("truth")
    if mode == "magnitude" or (mode == "auto" and unsigned):
        unsigned = True
        truth = np.abs(truth)
    else:
        unsigned = False
    sel = _window(spec, run) & np.isfinite(grad) & np.isfinite(truth)
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
    grad, _, column = _gradient(spec, run)
    ok = run.results["valid"] if spec.get("estimator") == "reference" else np.isfinite(grad)
    sel = _window(spec, run)
    if run.truth_gradient is not None:
        sel &= run.k < len(run.truth_gradient)
    expected = _expected_samples(spec, run)
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


def channel_flags(run: RunData, channel: int, sources: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Samples k at which the bench flagged `channel`, by what flagged it.

    GAP / STATUS_FLAG / CRC_ERROR / COUNTER_JUMP / DUPLICATE / LATE: an event of that kind
    naming the channel (CRC errors are placed at the sample received nearest in time).
    EXCLUDED: the estimator's `excluded` column names the channel at that sample.
    VOTE_FAIL: the sample's failed votes include both votes that a fault of this channel
    alone makes fail (VOTE_SIGNATURE) -- every vote uses every channel, so "a vote
    involving the channel" would mean any vote; the signature is what points at one.
    Per-sample columns are used for EXCLUDED and VOTE_FAIL because their events mark only
    changes: a state already set before the fault starts still counts from its onset."""
    out: dict[str, np.ndarray] = {}
    ev = run.events
    for name in sources:
        if name == "EXCLUDED":
            out[name] = run.k[run.results["excluded"] == channel]
        elif name == "VOTE_FAIL":
            failed = ~run.results["votes"]
            a, b = VOTE_SIGNATURE[channel]
            out[name] = run.k[failed[:, a] & failed[:, b]]
        else:
            sel = (ev["kind"] == int(EventKind[name])) & (ev["channel"] == channel)
            out[name] = run.event_k(ev[sel])
    return out


def check_fault_detected(spec: CheckSpec, run: RunData) -> Measurement:
    """Samples from each matching fault's onset to the first sample at which the bench
    flagged its channel (see :func:`channel_flags`); the value is the worst fault's."""
    if not run.faults and run.truth_gradient is None:
        return not_measured(spec, "error", "no emulator fault record in this run (real board)")
    channel = spec.get("channel")
    index = spec.get("fault")
    faults = [
        f
        for f in run.faults
        if (index is None or f.index == index) and (channel is None or channel in f.channels)
    ]
    faults = [f for f in faults if f.channels]
    if not faults:
        return not_measured(spec, "error", "no injected fault matches this check")
    sources = tuple(spec.get("flagged_by") or FLAG_SOURCES)
    per_fault = []
    worst: float | None = -1.0
    texts = []
    for f in faults:
        if f.onset_k is None:
            per_fault.append({"fault": f.label, "onset_k": None, "latency_samples": None})
            texts.append(f"{f.label}: had no effect on any sample, nothing to detect")
            worst = None
            continue
        chans = (channel,) if channel is not None else f.channels
        best: tuple[int, str, int] | None = None
        for ch in chans:
            for name, ks in channel_flags(run, ch, sources).items():
                later = ks[ks >= f.onset_k]
                if len(later):
                    k = int(later.min())
                    if best is None or k < best[0]:
                        best = (k, name, ch)
        if best is None:
            per_fault.append({"fault": f.label, "onset_k": f.onset_k, "latency_samples": None})
            texts.append(f"{f.label}: never flagged after its onset at sample {f.onset_k}")
            worst = None
            continue
        lat = best[0] - f.onset_k
        per_fault.append(
            {
                "fault": f.label,
                "onset_k": f.onset_k,
                "flag_k": best[0],
                "flagged_by": best[1],
                "latency_samples": lat,
                "latency_ms": 1000.0 * lat / run.rate_hz,
            }
        )
        texts.append(
            f"{f.label}: flagged by {best[1]} ch{best[2]} at sample {best[0]}, "
            f"{lat} samples ({1000.0 * lat / run.rate_hz:.4g} ms) after onset"
        )
        if worst is not None:
            worst = max(worst, float(lat))
    value = None if worst is None else worst
    return judge(spec, value, "; ".join(texts), faults=per_fault, flagged_by=list(sources))


def check_no_frame_loss(spec: CheckSpec, run: RunData) -> Measurement:
    """Frames lost anywhere between the sender and the log: sent vs received (emulated),
    received vs logged in run.mcap (counted from the file), and frames a full acquisition
    queue dropped (live). Counts that do not apply to a run are left out."""
    parts = []
    losses = [run.frames_dropped]
    if run.frames_sent is not None:
        losses.append(run.frames_sent - run.frames_received)
        parts.append(f"sent {run.frames_sent}")
    parts.append(f"received {run.frames_received}")
    if run.frames_logged is not None:
        losses.append(run.frames_received - run.frames_logged)
        parts.append(f"logged {run.frames_logged}")
    else:
        parts.append("logged: not counted")
    if run.frames_dropped:
        parts.append(f"dropped by a full queue {run.frames_dropped}")
    lost = max(abs(v) for v in losses)
    return judge(
        spec,
        float(lost),
        ", ".join(parts),
        sent=run.frames_sent,
        received=run.frames_received,
        logged=run.frames_logged,
        dropped=run.frames_dropped,
    )


def check_vote_failures(spec: CheckSpec, run: RunData) -> Measurement:
    """Samples in the window with a failed vote (`vote` = 1..3, or any vote)."""
    sel = _window(spec, run)
    votes = run.results["votes"][sel]
    v = spec.get("vote")
    failed = ~votes[:, v - 1] if v else ~votes.all(axis=1)
    count = int(failed.sum())
    per_vote = [int((~votes[:, i]).sum()) for i in range(3)]
    what = f"v{v}" if v else "any vote"
    return judge(
        spec,
        float(count),
        f"{count} of {len(votes)} samples failed {what} (v1/v2/v3: "
        + "/".join(map(str, per_vote))
        + ")",
        per_vote=per_vote,
        samples=len(votes),
    )


def check_gradient_jump(spec: CheckSpec, run: RunData) -> Measurement:
    """Largest change of the gradient between consecutive sampling instants that both have
    one: what a consumer of the gradient (a brake controller) would see as a step."""
    grad, _, column = _gradient(spec, run)
    sel = _window(spec, run)
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


def check_event_count(spec: CheckSpec, run: RunData) -> Measurement:
    """Events of the named kinds (optionally of one channel) in the window."""
    names = spec.get("events")
    ev = run.events
    sel = np.isin(ev["kind"], [int(EventKind[n]) for n in names])
    ch = spec.get("channel")
    if ch is not None:
        sel &= ev["channel"] == ch
    ev = ev[sel]
    k = run.event_k(ev)
    t = k / run.rate_hz
    win = np.ones(len(ev), dtype=bool)
    if spec.from_s is not None:
        win &= t >= spec.from_s - 1e-9
    if spec.to_s is not None:
        win &= t < spec.to_s - 1e-9
    ev = ev[win]
    counts = {n: int((ev["kind"] == int(EventKind[n])).sum()) for n in names}
    # SAMPLES_LOST and DROPPED carry a count in their value: count what they lost
    total = 0
    for n in names:
        rows = ev[ev["kind"] == int(EventKind[n])]
        total += int(rows["value"].sum()) if n in ("SAMPLES_LOST", "DROPPED") else len(rows)
    where = f" ch{ch}" if ch is not None else ""
    return judge(
        spec,
        float(total),
        ", ".join(f"{n}{where}: {c}" for n, c in counts.items()),
        counts=counts,
    )


def check_step_gradient(spec: CheckSpec, run: RunData) -> Measurement:
    """Operator steps: the gradient measured in each step's window against the gradient the
    step expected (the operator's reference reading when one was entered). `statistic` =
    "mean": error of the window's mean (a tilt-table calibration point); "max": worst
    single-sample error. The value is the worst step's."""
    steps = [s for s in run.steps if spec.get("step") in (None, s.index)]
    if not steps:
        return not_measured(spec, "error", "the run has no operator steps to measure")
    grad, unsigned, column = _gradient(spec, run)
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


def check_latency(spec: CheckSpec, run: RunData) -> Measurement:
    """Frame-to-result latency on the PC (wall clock), live runs only. An emulated run fed
    as fast as possible has no wall-clock latency to measure; use fault_detected for the
    latency that matters there (samples from a fault's onset to its flag)."""
    if run.latency_ms is None or not all(map(math.isfinite, run.latency_ms)):
        return not_measured(
            spec, "skip", f"no wall-clock latency in a {run.mode} run (live runs only)"
        )
    p50, p99 = run.latency_ms
    value = p99 if spec.get("percentile") == 99 else p50
    return judge(spec, value, f"p50 {p50:.3g} ms, p99 {p99:.3g} ms", p50=p50, p99=p99)


# --------------------------------------------------------------------------- registry

_WINDOW_HELP = "run-time window [from_s, to_s) in s (default: the whole run)"
_EST = Param(
    "choice",
    "reference",
    choices=tuple(ESTIMATORS),
    help="reference: the device's method; signed: the bench's estimator; magnitude: LS",
)

KINDS: dict[str, Kind] = {
    "gradient_error": Kind(
        check_gradient_error,
        "permil",
        {
            "estimator": _EST,
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
    "availability": Kind(
        check_availability,
        "fraction",
        {
            "estimator": _EST,
            "min_fraction": Param("number", required=True, lo=0.0, hi=1.0),
            "warn_fraction": Param("number", lo=0.0, hi=1.0),
        },
        Limit("min_fraction", "warn_fraction", upper=False),
        summary="fraction of sampling instants with a gradient",
    ),
    "fault_detected": Kind(
        check_fault_detected,
        "samples",
        {
            "channel": Param("integer", lo=1, hi=3),
            "fault": Param("integer", lo=1),
            "within_samples": Param("integer", required=True, lo=0),
            "warn_samples": Param("integer", lo=0),
            "flagged_by": Param("events", choices=FLAG_SOURCES),
        },
        Limit("within_samples", "warn_samples", upper=True),
        needs_truth=True,
        summary="samples from a fault's onset until the bench flags its channel",
    ),
    "no_frame_loss": Kind(
        check_no_frame_loss,
        "frames",
        {"max_frames": Param("integer", 0, lo=0)},
        Limit("max_frames", None, upper=True),
        summary="frames sent = received = logged in run.mcap",
    ),
    "vote_failures": Kind(
        check_vote_failures,
        "samples",
        {
            "vote": Param("integer", lo=1, hi=3),
            "max_count": Param("integer", required=True, lo=0),
            "warn_count": Param("integer", lo=0),
        },
        Limit("max_count", "warn_count", upper=True),
        summary="samples with a failed two-out-of-three vote",
    ),
    "gradient_jump": Kind(
        check_gradient_jump,
        "permil",
        {
            "estimator": _EST,
            "max_permil": Param("number", required=True, lo=0.0),
            "warn_permil": Param("number", lo=0.0),
        },
        Limit("max_permil", "warn_permil", upper=True),
        summary="largest gradient change between consecutive samples",
    ),
    "event_count": Kind(
        check_event_count,
        "events",
        {
            "events": Param("events", required=True, choices=tuple(k.name for k in EventKind)),
            "channel": Param("integer", lo=1, hi=3),
            "max_count": Param("integer", 0, lo=0),
            "warn_count": Param("integer", lo=0),
        },
        Limit("max_count", "warn_count", upper=True),
        summary="events of given kinds (CRC_ERROR, GAP, LINK_ERROR, ...)",
    ),
    "step_gradient": Kind(
        check_step_gradient,
        "permil",
        {
            "estimator": _EST,
            "statistic": Param("choice", "mean", choices=("mean", "max")),
            "step": Param("integer", lo=1),
            "max_permil": Param("number", required=True, lo=0.0),
            "warn_permil": Param("number", lo=0.0),
        },
        Limit("max_permil", "warn_permil", upper=True),
        needs_steps=True,
        summary="operator steps: measured vs expected gradient",
    ),
    "latency": Kind(
        check_latency,
        "ms",
        {
            "percentile": Param("choice", 99, choices=(50, 99)),
            "max_ms": Param("number", required=True, lo=0.0),
            "warn_ms": Param("number", lo=0.0),
        },
        Limit("max_ms", "warn_ms", upper=True),
        summary="frame-to-result latency on the PC (live runs)",
    ),
}


def run_check(spec: CheckSpec, run: RunData) -> Measurement:
    """One check; a bug or bad data inside it is the bench's failure (verdict error)."""
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


EXIT_CODES = {"pass": 0, "fail": 1, "error": 2}
