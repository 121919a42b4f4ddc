"""Checks on the frames: sent = received = logged, and how long the PC took per frame."""

from __future__ import annotations

import math

from bench.acceptance.checks.base import (
    CheckSpec,
    Kind,
    Limit,
    Param,
    judge,
    not_measured,
    register,
)
from bench.acceptance.model import Measurement, RunData
from bench.records.events import EventKind


def check_no_frame_loss(spec: CheckSpec, run: RunData) -> Measurement:
    """Frames lost anywhere between the sender and the log: sent vs received (emulated),
    received vs logged in run.mcap (counted from the file), frames a full acquisition
    queue dropped (live; a replay: the DROPPED events its recording holds) and frames the
    kernel dropped at a full socket buffer (SOCKET_OVERFLOW events). Counts that do not
    apply to a run are left out."""
    parts = []
    overflow = run.events[run.events["kind"] == EventKind.SOCKET_OVERFLOW]
    kernel = int(overflow["value"].sum()) if len(overflow) else 0
    losses = [run.frames_dropped, kernel]
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
    if kernel:
        parts.append(f"dropped by the kernel {kernel}")
    lost = max(abs(v) for v in losses)
    return judge(
        spec,
        float(lost),
        ", ".join(parts),
        sent=run.frames_sent,
        received=run.frames_received,
        logged=run.frames_logged,
        dropped=run.frames_dropped,
        kernel_dropped=kernel,
    )


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


register(
    "no_frame_loss",
    Kind(
        check_no_frame_loss,
        "frames",
        {"max_frames": Param("integer", 0, lo=0)},
        Limit("max_frames", None, upper=True),
        summary="frames sent = received = logged in run.mcap",
    ),
)
register(
    "latency",
    Kind(
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
)
