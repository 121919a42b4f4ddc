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

from typing import TYPE_CHECKING, Any

import numpy as np
from numba import njit

from bench.config import Config
from bench.fusion.isolation import (
    ExclusionLatch,
    Reason,
    ResidualIsolator,
    StuckDetector,
    carry_named,
)
from bench.fusion.joint import JointFilter
from bench.fusion.least_squares import (
    FULL,
    geometry,
    mask_code,
    solve_channels,
)
from bench.fusion.speed_ref import ReferenceAcceleration
from bench.records.events import EVENT_DTYPE
from bench.records.results import ESTIMATE_DTYPE
from protocol.layout import TICK_S

if TYPE_CHECKING:
    from bench.fusion.model.log import ModelFeed

_EXCLUDED_OF_MASK = np.array((1, 2, 1, 3, 1, 2, 1, 0), dtype=np.uint8)
"""Channel reported as excluded, by mask of channels used: the one left out of a pair,
the lowest unused one when fewer than two remain, 0 with all three."""
_RESIDUAL, _STUCK, _STATUS = int(Reason.RESIDUAL), int(Reason.STUCK), int(Reason.STATUS)


def _ticks(seconds: float) -> int:
    return max(round(seconds / TICK_S), 1)


@njit(cache=True)
def _reasons_run(single, stuck, present, usable, reason):  # type: ignore[no-untyped-def]
    """(3, N) reason per channel and sample, 0 for none; status beats stuck beats residual."""
    for i in range(len(single)):
        for k in range(3):
            if present[k, i] and not usable[k, i]:
                reason[k, i] = _STATUS
            elif stuck[k, i]:
                reason[k, i] = _STUCK
            else:
                reason[k, i] = _RESIDUAL if single[i] == k else 0


@njit(cache=True)
def _starts_run(before, latched, reason, out):  # type: ignore[no-untyped-def]
    """(N,) the channel (1..3) whose exclusion by the residual or as stuck starts at this
    sample, else 0 (latched flags (3,) before the batch, (3, N) in it): its error grew
    slowly until then and may sit in the gradient (the lowest channel when several start)."""
    for i in range(len(out)):
        out[i] = 0
        for k in range(3):
            was = latched[k, i - 1] if i else before[k]
            slow = reason[k, i] == _RESIDUAL or reason[k, i] == _STUCK
            if latched[k, i] and not was and slow:
                out[i] = k + 1
                break


KERNELS = (_reasons_run, _starts_run)
"""This module's compiled loops (the constructor compiles or loads them)."""


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
        solve_channels(np.zeros((3, 0)), np.zeros(0, np.int64), self.geo, self.g)  # load now
        none = np.zeros((3, 0), np.bool_)
        _reasons_run(np.zeros(0, np.int8), none, none, none, np.zeros((3, 0), np.int64))
        _starts_run(np.zeros(3, np.bool_), none, np.zeros((3, 0), np.int64), np.zeros(0, np.int8))
        self._named = -1  # the channel the current residual alarm named (-1: none)
        self.log: ModelFeed | None = None  # the filter's inputs, for the model (log or live)

    def push(
        self, samples: np.ndarray, acc: np.ndarray, usable: np.ndarray, speeds: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Estimates for ``samples`` (SAMPLE_DTYPE, in order) and EXCLUDED/READMITTED events.

        acc: (N, 3) calibrated m/s^2 of every channel; usable: (N, 3) present and status OK;
        speeds: SPEED_REF records (SPEED_DTYPE) of this pipeline step, arrival order.
        """
        self.a_ref.buffer(speeds)
        n = len(samples)
        if n == 0:
            return np.zeros(0, dtype=ESTIMATE_DTYPE), np.zeros(0, dtype=EVENT_DTYPE)
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
        reason = np.empty((3, n), np.int64)
        _reasons_run(single, stuck, present, usable, reason)
        before = self.latch.latched.copy()
        latched, events = self.latch.push(ticks, samples["t"], samples["n"], reason)
        used = usable & ~latched
        out = np.empty(n, dtype=ESTIMATE_DTYPE)
        code = np.full(n, FULL, dtype=np.int64) if used.all() else mask_code(used)
        u, w, out["gradient_ls"] = solve_channels(acc, code, self.geo, self.g)
        out["degraded"] = code != FULL
        out["excluded"] = _EXCLUDED_OF_MASK[code]
        starts = np.empty(n, np.int8)
        _starts_run(before, latched, reason, starts)
        if self.log is not None:
            self.log.add(ticks * TICK_S, acc.T, code, self.a_ref.applied, samples["t"])
        fo = self.filter.push(ticks * TICK_S, u, w, code, residual, starts, self.a_ref.applied)
        out["gradient_signed"] = fo.gradient
        out["gradient_sigma"] = fo.sigma
        out["odometer_suspect"] = fo.suspect
        out["coasting"] = fo.coasting
        out["u"] = u
        out["w"] = w
        out["a_ref"] = a_ref
        out["residual"] = residual
        return out, events


def kernel_is_ready() -> bool:
    """True when the estimator's compiled kernels are loaded in this process or wait in
    numba's disk cache, valid for this machine and these sources: starting needs no compile.
    (The cache index is keyed by signature and the target machine's magic; numba returns
    no entries for a source changed since, and kernel_cache drops stale ones at import.)"""
    from bench.fusion import isolation, joint_kernel, least_squares, speed_ref

    kernels = (
        joint_kernel.run,
        *isolation.KERNELS,
        *speed_ref.KERNELS,
        *least_squares.KERNELS,
        *KERNELS,
    )
    return all(_is_ready(k) for k in kernels)


def _is_ready(kernel: Any) -> bool:
    if getattr(kernel, "overloads", None):
        return True
    try:
        index = kernel._cache._cache_file._load_index()
        magic = kernel.targetctx.codegen().magic_tuple()
    except Exception:  # no cache (read-only install, numba's jit disabled): it compiles
        return False
    return any(key[1] == magic for key in index)


def warm_up() -> None:
    """Compile the estimator's kernels, or load them from numba's disk cache."""
    from bench.fusion.joint import warm_up as joint_warm_up

    joint_warm_up()
    Estimator(Config())  # its stages compile or load their loops when built
