"""Reference acceleration a_ref from SPEED_REF, aligned to the board's samples.

Causality (what makes the output independent of batching): speed frames are buffered,
and a sample applies exactly the buffered frames whose arrival index ``seq`` is below the
largest ``seq`` of all samples so far (``R``). That set depends only on the stream, never on
where a batch ends, and it never contains a frame that arrived after the sample's data.
``R`` is non-decreasing, so frames are applied in arrival order, each exactly once, and
the filter (:class:`~bench.fusion.kalman.SpeedKalman`) runs once over the whole stream.
The first sample that applies a frame is its *anchor*.

Clock alignment. Board time b (sample ticks, unwrapped) and odometer time o (frame
timestamps, unwrapped here) run on two unsynchronised 100 us clocks. Where receive times
t are finite, each stream's offset to the receive clock is the least observed latency
``min(t - clock)``, made leaky (it may rise by ``clock_drift_ppm`` per second) so it
follows a clock that runs slow. A frame measured at o then happened at board time
o + off_odo - off_board (off_board taken at the frame's anchor). What the minima keep is
each stream's least latency; their difference cannot be seen in receive times and counts
as zero (both streams share the bus), so a frame delayed on its way still maps to the
instant it was measured. Without receive times (a NaN involved) the fallback is arrival
order: a frame counts as measured at its anchor's board time, and the odometer's 6.5536 s
timestamp wraps are resolved from the anchors' board-time steps instead.

What the alignment decides: the age of the newest applied frame at each sample's instant
(coasting: after ``coast_s`` without SPEED_REF a_ref is unavailable, NaN). With the
constant-acceleration model the acceleration predicted to any later instant equals the
filter's latest estimate, so no extrapolation is applied to the value itself.

Standstill: when the odometer has reported exactly 0 mm/s for ``standstill_s`` of its
own time, a_ref is exactly 0.0. A gap longer than ``coast_s`` between frames restarts the
filter. a_ref is also unavailable while the filter's own acceleration uncertainty exceeds
``a_ref_sigma_mps2``: for a fraction of a second after a start and after each change of
acceleration the filter detects (see :mod:`bench.fusion.kalman`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from bench.config import EstimatorSettings
from bench.fusion.isolation import NEVER
from bench.fusion.kalman import SpeedKalman
from bench.records.board import SPEED_DTYPE
from bench.records.samples import MAX_BRIDGE_TICKS, SAMPLE_DTYPE
from protocol.layout import TICK_S, TS_WRAP

_INF = math.inf


@njit(cache=True)
def _leaky_min_run(x, clock_s, rho, base, out):  # type: ignore[no-untyped-def]
    run = base
    for i in range(len(x)):
        drift = rho * clock_s[i]
        if math.isfinite(x[i]):
            run = min(run, x[i] - drift)
        out[i] = drift + run if math.isfinite(run) else math.nan
    return run


def leaky_min(
    x: np.ndarray, clock_s: np.ndarray, rho: float, base: float
) -> tuple[np.ndarray, float]:
    """Offsets min_j<=i (x_j + rho*(clock_i - clock_j)) for every i, non-finite x skipped.

    Computed as rho*clock_i + running min of (x_j - rho*clock_j): exact (min does not
    round), so the same whatever the batching. ``base`` carries the running min.
    """
    out = np.empty(len(x))
    last = _leaky_min_run(_f8(x), _f8(clock_s), rho, base, out)
    return out, float(last)


@njit(cache=True)
def _align(b, x, seq, rho, state, pending_seq, board_off, anchors):  # type: ignore[no-untyped-def]
    """Board offsets per sample (from the running min ``state[0]``), and the anchor of each
    buffered frame: the first sample whose running max of seq (from ``state[1]``) exceeds
    the frame's seq, or len(b). Returns how many frames anchor in this batch."""
    state[0] = _leaky_min_run(x, b, rho, state[0], board_off)
    run_max, j, n = state[1], 0, len(b)
    for i in range(n):
        run_max = max(run_max, seq[i])
        while j < len(pending_seq) and pending_seq[j] < run_max:
            anchors[j] = i
            j += 1
    state[1] = run_max
    anchors[j:] = n
    return j


@njit(cache=True)
def _expand(b, anchors, acc, when, still, ok, coast_s, out):  # type: ignore[no-untyped-def]
    """a_ref per sample from the newest frame it applies (index 0: the one applied before
    this batch, k: the k-th new one, from its anchor on); NaN once older than coast_s."""
    j = 0
    for i in range(len(b)):
        while j < len(anchors) and anchors[j] <= i:
            j += 1
        v = 0.0 if still[j] else acc[j]
        if not (ok[j] or still[j]):
            v = math.nan
        out[i] = v if b[i] - when[j] <= coast_s else math.nan  # stale, or no frame yet


def _f8(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float64)


def _plausible(step_ticks: np.ndarray) -> np.ndarray:
    """Finite and no longer than the longest gap receive time is trusted to bridge."""
    return np.abs(step_ticks) <= MAX_BRIDGE_TICKS  # False for NaN and inf


class ReferenceAcceleration:
    """Stateful: :meth:`push` every batch of samples, of any length, in sample order."""

    def __init__(self, settings: EstimatorSettings) -> None:
        self.settings = settings
        self.kf = SpeedKalman(settings.speed_noise_mps, settings.jerk_psd)
        self.rho = settings.clock_drift_ppm * 1e-6
        self._pending = np.zeros(0, dtype=SPEED_DTYPE)  # buffered, not yet applied
        self._coast_s = settings.coast_s
        # the running min for the board offset, and R, the largest sample seq so far
        self._state = np.array([_INF, -1.0])
        self._odo_base = _INF  # running min for the odometer offset
        self._started = False
        self._restart = np.zeros(0, dtype=bool)
        # the last applied frame, for unwrapping the odometer timestamp
        self._prev_ts = 0
        self._prev_t = math.nan
        self._prev_anchor_b = 0.0
        self._odo_ticks = 0
        self._zero_since: int | None = None  # odometer ticks of the first 0 mm/s of a run
        # the newest applied frame: acceleration, board time, standstill, filter settled
        self._last: tuple[float, float, bool, bool] = (math.nan, math.nan, False, False)
        # frames applied by the last push (anchor index, board time measured, speed m/s,
        # restart, standstill), for the joint filter
        self.applied: tuple[np.ndarray, ...] | None = None
        self.push(np.zeros(0, SAMPLE_DTYPE))  # compile or load the loops now, not live
        leaky_min(np.zeros(0), np.zeros(0), self.rho, _INF)

    def buffer(self, speeds: np.ndarray) -> None:
        """Keep this step's SPEED_REF frames until samples may apply them."""
        if len(speeds):
            pending = self._pending
            self._pending = np.concatenate([pending, speeds]) if len(pending) else speeds

    def push(self, samples: np.ndarray) -> np.ndarray:
        """a_ref (m/s^2, NaN = unavailable) for each sample, in order."""
        b = samples["ticks"] * TICK_S  # board time, s
        n, pending = len(b), self._pending
        board_off, anchors = np.empty(n), np.empty(len(pending), np.int64)
        seq = np.ascontiguousarray(samples["seq"], dtype=np.int64)
        x = _f8(samples["t"] - b)
        pending_seq = np.ascontiguousarray(pending["seq"], dtype=np.int64)
        k_new = _align(b, x, seq, self.rho, self._state, pending_seq, board_off, anchors)
        last = self._last
        self.applied = None
        if k_new:
            anchors = anchors[:k_new]
            frames = pending[:k_new]
            acc, when, still, ok = self._apply(frames, b[anchors], board_off[anchors])
            self.applied = (anchors, when, frames["speed"] * 1e-3, self._restart, still)
            self._pending = pending[k_new:]
            self._last = (float(acc[-1]), float(when[-1]), bool(still[-1]), bool(ok[-1]))
            acc, when, still, ok = (
                np.concatenate([[h], x]) for h, x in zip(last, (acc, when, still, ok), strict=True)
            )
        else:
            anchors = anchors[:0]
            acc, when, still, ok = (np.array([v]) for v in last)
        out = np.empty(n)
        _expand(b, anchors, acc, when, still, ok, self._coast_s, out)
        return out

    # -- internals -------------------------------------------------------------------------
    def _apply(
        self, frames: np.ndarray, anchor_b: np.ndarray, anchor_off: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Run the filter over newly applied frames (vectorised over frames, exact either
        way); per frame: acceleration, board time, standstill, filter settled."""
        s = self.settings
        ts = frames["timestamp"].astype(np.int64)
        t = frames["t"]
        # unwrap the odometer timestamps (wraps from receive times, else from anchor times)
        prev_ts = np.concatenate(([self._prev_ts], ts[:-1]))
        prev_t = np.concatenate(([self._prev_t], t[:-1]))
        prev_b = np.concatenate(([self._prev_anchor_b], anchor_b[:-1]))
        d = (ts - prev_ts) % TS_WRAP
        # receive time bridges wraps only over plausible gaps (as in bench.pipeline.assembly): a
        # missing or absurd receive time (NaN, inf, 1e300, -1) falls back to board time
        with np.errstate(invalid="ignore", over="ignore"):
            step = (t - prev_t) / TICK_S
            step = np.where(_plausible(step), step, (anchor_b - prev_b) / TICK_S)
            wraps = np.where(_plausible(step), np.rint((step - d) / TS_WRAP), 0.0)
        d += TS_WRAP * np.maximum(wraps, 0.0).astype(np.int64)
        restart = d > s.coast_s / TICK_S  # SPEED_REF was away too long: the state is stale
        if not self._started:
            d[0] = ts[0] - self._odo_ticks
            restart[0] = True
            self._started = True
        odo = self._odo_ticks + np.cumsum(d)
        # standstill: 0 mm/s without a break for standstill_s of odometer time
        zero = frames["speed"] == 0
        before = np.concatenate(([self._zero_since is not None], zero[:-1]))
        starts = zero & (~before | restart)
        carry = NEVER if self._zero_since is None else self._zero_since
        since = np.maximum.accumulate(np.concatenate(([carry], np.where(starts, odo, NEVER))))[1:]
        still = zero & (odo - since >= s.standstill_s / TICK_S)
        # odometer time -> board time
        o = odo * TICK_S
        odo_off, self._odo_base = leaky_min(t - o, o, self.rho, self._odo_base)
        with np.errstate(invalid="ignore"):
            mapped = o + odo_off - anchor_off
        when = np.where(np.isfinite(mapped), mapped, anchor_b)
        speed = (frames["speed"] * 1e-3).tolist()
        acc, var = self.kf.run((d * TICK_S).tolist(), speed, restart.tolist())
        self._restart = restart
        ok = np.array(var) <= s.a_ref_sigma_mps2 * s.a_ref_sigma_mps2
        self._prev_ts, self._prev_t = int(ts[-1]), float(t[-1])
        self._prev_anchor_b = float(anchor_b[-1])
        self._odo_ticks = int(odo[-1])
        self._zero_since = int(since[-1]) if zero[-1] else None
        return np.array(acc), when, still, ok


KERNELS = (_leaky_min_run, _align, _expand)
"""The compiled loops of this module (the constructor compiles or loads them)."""
