"""The bench's own estimator (METHOD.md section 5; the model in docs/ESTIMATOR.md).

Per sample: exclude faulty channels (missing, status-flagged, stuck, singled out by the
residual; exclusions held with hysteresis), solve the specific force (u, w) by least
squares from the channels left, and feed u, w and the SPEED_REF frames to the joint filter
(:mod:`bench.fusion.joint`), whose state s = g sin(alpha) gives the signed gradient and its
sigma. a_ref, the odometer's own acceleration, serves the residual isolation only.

Its error from an error e in one channel grows like e/g, where the reference method's
grows like sqrt(e/g) near level track, and it keeps the sign. No I/O; the same stream
gives bit-identical float64 output however it is cut into batches: each stage carries its
state and uses element-wise or exact operations only, and the filter is one compiled loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from bench.config import Config
from bench.fusion.isolation import (
    ExclusionLatch,
    Reason,
    ResidualIsolator,
    StuckDetector,
    carry_named,
    carry_named_one,
)
from bench.fusion.joint import JointFilter
from bench.fusion.least_squares import (
    FULL,
    geometry,
    magnitude_gradient,
    magnitude_gradient_one,
    mask_code,
    solve_channels,
    solve_full,
    solve_one,
)
from bench.fusion.speed_ref import ReferenceAcceleration
from bench.records.events import EVENT_DTYPE
from protocol.layout import TICK_S

if TYPE_CHECKING:
    from bench.fusion.model.log import ModelLog

ESTIMATE_DTYPE = np.dtype(
    [
        ("gradient_signed", "<f8"),
        ("gradient_ls", "<f8"),
        ("u", "<f8"),
        ("w", "<f8"),
        ("a_ref", "<f8"),
        ("residual", "<f8"),
        ("degraded", "?"),
        ("excluded", "u1"),
        ("gradient_sigma", "<f8"),
        ("odometer_suspect", "?"),
        ("coasting", "?"),
    ]
)

EXCLUDED_OF_MASK = (1, 2, 1, 3, 1, 2, 1, 0)
"""Channel reported as excluded, by mask of channels used: the one left out of a pair,
the lowest unused one when fewer than two remain, 0 with all three."""
_EXCLUDED_OF_MASK = np.array(EXCLUDED_OF_MASK, dtype=np.uint8)
_RESIDUAL, _STUCK, _STATUS = int(Reason.RESIDUAL), int(Reason.STUCK), int(Reason.STATUS)
_NO_EVENTS = np.zeros(0, dtype=EVENT_DTYPE)
SCALAR_MAX = 16
"""Batches up to this many samples take the scalar path (live runs: the fixed cost of
numpy calls would dominate); longer ones the vectorised path. Same results either way."""


def _ticks(seconds: float) -> int:
    return max(round(seconds / TICK_S), 1)


_NO_REASON = (0, 0, 0)


def _reason(single: int, stuck: list[bool], present: list[bool], ok: list[bool]) -> list[int]:
    """Scalar twin of :func:`_reasons` for one sample."""
    reason = [0, 0, 0]
    if single >= 0:
        reason[single] = _RESIDUAL
    for k in range(3):
        if stuck[k]:
            reason[k] = _STUCK
        if present[k] and not ok[k]:
            reason[k] = _STATUS
    return reason


def _reasons(single: np.ndarray, stuck: np.ndarray, status: np.ndarray) -> np.ndarray:
    """(3, N) reason per channel and sample, 0 for none; status beats stuck beats residual."""
    reason = np.zeros(stuck.shape, dtype=np.uint8)
    hit = np.flatnonzero(single >= 0)
    if len(hit):
        reason[single[hit], hit] = _RESIDUAL
    if stuck.any():
        np.copyto(reason, _STUCK, where=stuck)
    if status.any():
        np.copyto(reason, _STATUS, where=status)
    return reason


class Estimator:
    """Stateful; :meth:`push` every batch of samples in order (see bench.pipeline.steps)."""

    def __init__(self, config: Config) -> None:
        self.config = config
        s = config.estimator
        self.g = config.g
        self.geo = geometry(config.angles_rad)
        self.a_ref = ReferenceAcceleration(s)
        self.stuck = StuckDetector(_ticks(s.stuck_window_s))
        window = max(round(s.residual_window_s * config.sample_rate_hz), 1)
        self.isolator = ResidualIsolator(self.geo, config.g, s.residual_limit_mps2, window)
        self.latch = ExclusionLatch(_ticks(s.recover_s))
        self.filter = JointFilter(config, self.geo)
        self._was_latched = [False, False, False]
        self._named = -1  # the channel the current residual alarm named (-1: none)
        self.log: ModelLog | None = None  # keeps the filter's inputs for the smoother

    def push(
        self, samples: np.ndarray, acc: np.ndarray, usable: np.ndarray, speeds: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Estimates for ``samples`` (SAMPLE_DTYPE, in order) and EXCLUDED/READMITTED events.

        acc: (N, 3) calibrated m/s^2 of every channel; usable: (N, 3) present and status OK;
        speeds: SPEED_REF records (SPEED_DTYPE) of this pipeline step, arrival order.
        """
        self.buffer_speeds(speeds)
        n = len(samples)
        if n == 0:
            return np.zeros(0, dtype=ESTIMATE_DTYPE), np.zeros(0, dtype=EVENT_DTYPE)
        if n <= SCALAR_MAX:
            return self._push_scalar(samples, acc, usable)
        return self._push_vector(samples, acc, usable)

    def buffer_speeds(self, speeds: np.ndarray) -> None:
        """Keep this step's SPEED_REF records for the reference acceleration."""
        self.a_ref.buffer(speeds)

    def _push_vector(
        self, samples: np.ndarray, acc: np.ndarray, usable: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        n = len(samples)
        a_ref = self.a_ref.push(samples)
        ticks = np.ascontiguousarray(samples["ticks"])
        # channel-major (3, N) and contiguous from here on: one copy each, then every
        # operation runs along contiguous rows instead of strided columns
        present, code, acc, usable = (
            np.ascontiguousarray(x.T) for x in (samples["present"], samples["code"], acc, usable)
        )
        stuck = self.stuck.push(ticks, code, present)
        healthy = usable & ~stuck
        cand = healthy[0] & healthy[1] & healthy[2]
        acc_healthy = acc if cand.all() else np.where(healthy, acc, 0.0)
        residual, single = self.isolator.push(acc_healthy, cand, a_ref)
        single, self._named = carry_named(single, cand, self._named)
        reason = _reasons(single, stuck, present & ~usable)
        latched, events = self.latch.push(ticks, samples["t"], samples["n"], reason)
        used = usable & ~latched
        out = np.empty(n, dtype=ESTIMATE_DTYPE)
        if used.all():
            u, w = solve_full(acc, self.geo)
            out["degraded"] = False
            out["excluded"] = 0
            code = np.full(n, FULL, dtype=np.int64)
        else:
            code = mask_code(used)
            u, w = solve_channels(np.where(used, acc, 0.0), code, self.geo)
            out["degraded"] = code != FULL
            out["excluded"] = _EXCLUDED_OF_MASK[code]
        starts = self._exclusion_starts(latched, reason)
        if self.log is not None:
            self.log.add(ticks * TICK_S, acc.T, code, self.a_ref.applied)
        fo = self.filter.push(ticks * TICK_S, u, w, code, residual, starts, self.a_ref.applied)
        out["gradient_signed"] = fo.gradient
        out["gradient_sigma"] = fo.sigma
        out["odometer_suspect"] = fo.suspect
        out["coasting"] = fo.coasting
        out["gradient_ls"] = magnitude_gradient(w, self.g)
        out["u"] = u
        out["w"] = w
        out["a_ref"] = a_ref
        out["residual"] = residual
        return out, events

    def _exclusion_starts(self, latched: np.ndarray, reason: np.ndarray) -> np.ndarray:
        """(N,) int8: the channel (1..3) whose exclusion by the residual or as stuck starts
        at this sample, else 0 ((3, N) latched flags and reasons): its error grew slowly
        until then and may sit in the gradient (the lowest channel when several start)."""
        prev = np.empty_like(latched)
        prev[:, 0] = self._was_latched
        prev[:, 1:] = latched[:, :-1]
        self._was_latched = latched[:, -1].tolist()
        new = latched & ~prev & ((reason == _RESIDUAL) | (reason == _STUCK))
        out = np.where(new[2], 3, 0).astype(np.int8)
        np.copyto(out, 2, where=new[1])
        np.copyto(out, 1, where=new[0])
        return out

    def _push_scalar(
        self, samples: np.ndarray, acc: np.ndarray, usable: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Twin of :meth:`_push_vector`, one sample at a time in Python floats."""
        rows, events = self.push_rows(
            samples["ticks"].tolist(),
            samples["t"].tolist(),
            samples["seq"].tolist(),
            samples["n"].tolist(),
            samples["code"].tolist(),
            samples["present"].tolist(),
            acc.tolist(),
            usable.tolist(),
        )
        out = np.array(rows, dtype=ESTIMATE_DTYPE)
        return out, np.array(events, dtype=EVENT_DTYPE) if events else _NO_EVENTS

    def push_rows(
        self,
        ticks_l: list[int],
        t_l: list[float],
        seq_l: list[int],
        n_l: list[int],
        code_l: list[list[int]],
        present_l: list[list[bool]],
        acc_l: list[list[float]],
        usable_l: list[list[bool]],
    ) -> tuple[list[tuple], list[tuple]]:
        """The scalar path on Python lists (the pipeline's own scalar step calls it, after
        :meth:`buffer_speeds`): ESTIMATE_DTYPE rows as tuples, EVENT_DTYPE rows as tuples."""
        rows = []
        events: list[tuple] = []
        geo, g = self.geo, self.g
        a_ref_step, stuck_step = self.a_ref.step, self.stuck.step
        isolate, latch = self.isolator.step, self.latch.step
        applied = self.a_ref.rows
        applied.clear()
        anchors: list[int] = []
        u_l: list[float] = []
        w_l: list[float] = []
        mask_l: list[int] = []
        res_l: list[float] = []
        start_l: list[int] = []
        was_latched = self._was_latched
        named = self._named
        for i, (ticks, t, seq, n, code, present, a, ok) in enumerate(
            zip(ticks_l, t_l, seq_l, n_l, code_l, present_l, acc_l, usable_l, strict=True)
        ):
            a_ref = a_ref_step(ticks, t, seq)
            if len(applied) > len(anchors):
                anchors += [i] * (len(applied) - len(anchors))
            stuck = stuck_step(ticks, code, present)
            a0, a1, a2 = a
            o0, o1, o2 = ok
            s0, s1, s2 = stuck
            h0, h1, h2 = o0 and not s0, o1 and not s1, o2 and not s2
            residual, single = isolate(
                (a0 if h0 else 0.0, a1 if h1 else 0.0, a2 if h2 else 0.0), h0 and h1 and h2, a_ref
            )
            single, named = carry_named_one(single, h0 and h1 and h2, named)
            reason = (
                _reason(single, stuck, present, ok)
                if single >= 0 or not (h0 and h1 and h2)
                else _NO_REASON
            )
            (l0, l1, l2), ev = latch(ticks, t, n, reason)
            w0, w1, w2 = was_latched
            slow = (_RESIDUAL, _STUCK)
            start_l.append(
                1
                if l0 and not w0 and reason[0] in slow
                else 2
                if l1 and not w1 and reason[1] in slow
                else 3
                if l2 and not w2 and reason[2] in slow
                else 0
            )
            was_latched = [l0, l1, l2]
            if ev:
                events += ev
            u0, u1, u2 = o0 and not l0, o1 and not l1, o2 and not l2
            mask = u0 + 2 * u1 + 4 * u2
            if mask != FULL:
                a = (a0 if u0 else 0.0, a1 if u1 else 0.0, a2 if u2 else 0.0)
            u, w = solve_one(a, mask, geo)
            u_l.append(u)
            w_l.append(w)
            mask_l.append(mask)
            res_l.append(residual)
            rows.append(
                (
                    magnitude_gradient_one(w, g),
                    u,
                    w,
                    a_ref,
                    residual,
                    mask != FULL,
                    EXCLUDED_OF_MASK[mask],
                )
            )
        self._was_latched = was_latched
        self._named = named
        frames = None
        if applied:
            when, speed, restart, still = zip(*applied, strict=True)
            frames = (
                np.array(anchors, dtype=np.int64),
                np.array(when, dtype=np.float64),
                np.array(speed, dtype=np.float64),
                np.array(restart, dtype=np.bool_),
                np.array(still, dtype=np.bool_),
            )
            applied.clear()
        if self.log is not None:
            b_l = np.array(ticks_l, dtype=np.int64) * TICK_S
            self.log.add(b_l, np.array(acc_l, dtype=np.float64), np.array(mask_l), frames)
        fo = self.filter.push(
            np.array(ticks_l, dtype=np.int64) * TICK_S,
            np.array(u_l),
            np.array(w_l),
            np.array(mask_l, dtype=np.int64),
            np.array(res_l),
            np.array(start_l, dtype=np.int8),
            frames,
        )
        out = [
            (gr, *row, sg, su, co)
            for gr, row, sg, su, co in zip(
                fo.gradient.tolist(),
                rows,
                fo.sigma.tolist(),
                fo.suspect.tolist(),
                fo.coasting.tolist(),
                strict=True,
            )
        ]
        return out, events


def kernel_is_ready() -> bool:
    """True when the estimator's compiled kernel is loaded in this process or waits in
    numba's disk cache, valid for this machine and these sources: starting needs no compile.
    (The cache index is keyed by signature and the target machine's magic; numba returns
    no entries for a source changed since, and kernel_cache drops stale ones at import.)"""
    from bench.fusion import joint_kernel

    run = joint_kernel.run
    if getattr(run, "overloads", None):
        return True
    try:
        index = run._cache._cache_file._load_index()
        magic = run.targetctx.codegen().magic_tuple()
    except Exception:  # no cache (read-only install, numba's jit disabled): it compiles
        return False
    return any(key[1] == magic for key in index)


def warm_up() -> None:
    """Compile the estimator's kernel, or load it from numba's disk cache."""
    from bench.fusion.joint import warm_up as joint_warm_up

    joint_warm_up()
