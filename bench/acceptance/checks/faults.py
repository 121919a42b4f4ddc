"""Checks on what the bench flagged: how fast it flagged an injected fault, failed votes,
events of given kinds."""

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
from bench.records.events import EventKind

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
    per_fault: list[dict[str, object]] = []
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


def check_vote_failures(spec: CheckSpec, run: RunData) -> Measurement:
    """Samples in the window with a failed vote (`vote` = 1..3, or any vote)."""
    sel = in_window(spec, run)
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


register(
    "fault_detected",
    Kind(
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
)
register(
    "vote_failures",
    Kind(
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
)
register(
    "event_count",
    Kind(
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
)
