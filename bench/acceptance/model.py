"""What an acceptance run produces and its checks read: run data, measurements, verdicts.

Checks are pure functions of :class:`RunData` (arrays and counts, no files, no emulator
objects), so a run and the replay of its MCAP log give the same measurements. Time in a plan
is *run time*: sample k of the run (k = 0 for the first sampling instant) is at
k / sample_rate seconds, on the board's clock, not the PC's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

VERDICTS = ("pass", "warn", "fail", "error", "skip")

EXIT_CODES = {"pass": 0, "fail": 1, "error": 2}


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
            "value": json_num(self.value),
            "unit": self.unit,
            "limits": self.limits,
            "verdict": self.verdict,
            "detail": self.detail,
            "window_s": [self.from_s, self.to_s],
            "margin": json_num(self.margin),
            "expect": self.expect,
            "extra": jsonable(self.extra),
        }


def json_num(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else float(v)


def jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        return json_num(obj)
    return obj
