"""The model over a whole recorded run: its forward pass, then the RTS smoother (issue 26).

:class:`ModelLog` is handed what the estimator's filter is given, push by push (board time,
calibrated channel readings, the channels the isolation lets through, the SPEED_REF
frames applied), and keeps it. :meth:`ModelLog.smooth` runs the model's forward pass and
its smoother over all of it and gives, per sample in the order pushed, the smoothed
gradient and its sigma: what `bench replay --smooth` writes. It runs after the run, so it
cannot change the live estimator's results, and it is the same whatever the batch cut
(the recorded arrays are the concatenation of the pushes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from bench.config import Config
from bench.fusion.model import jump, run, smoother, state

BLOCK_S = 0.02
"""The model's step: the channel readings are averaged over blocks of at most this long."""
ODOMETER_GATE = 25.0
"""A SPEED_REF reading with NIS beyond this (5 sigma) is not applied (slip, slide)."""
CHANNEL_GATE = 50.0
"""A block's readings beyond this NIS are tried without each channel in turn."""
PASSES = 2
"""Forward-backward passes: the first finds the slipping frames, the second leaves them out."""
SLIP_SIGMA = 4.0
"""A SPEED_REF frame this many sigma off the smoothed speed is a slip or slide reading: the
smoother's second pass leaves it out, with the frames within SLIP_MARGIN_S of it."""
SLIP_MARGIN_S = 0.3
"""A slide or slip builds up and decays over a WSP cycle (0.6-1.6 s): the frames this
close to one found are of the same episode."""
ODOMETER_FLOOR_MPS = 0.01
"""Odometer noise added to the settings' (1-sigma, m/s): what a wheel speed reads of a
car's pitch and bounce and of its own resolution, beyond the sensor's white noise."""


@dataclass(frozen=True, slots=True)
class Smoothed:
    """Per sample (in the order pushed): the model's gradient and its 1-sigma, permil."""

    filtered: np.ndarray  # forward pass, NaN where fewer than two channels or withheld
    filtered_sigma: np.ndarray
    smoothed: np.ndarray  # RTS, NaN where fewer than two channels or withheld
    smoothed_sigma: np.ndarray
    wheel_scale: float  # the odometer's wheel-scale error E (SPEED_REF = (1 + E) v)
    wheel_scale_sigma: float
    # every state smoothed, per block of `block` samples (sample i is in block i // block):
    # (blocks, NX) values and 1-sigmas, columns in state.NAMES order
    states: np.ndarray = field(default_factory=lambda: np.zeros((0, state.NX)))
    states_sigma: np.ndarray = field(default_factory=lambda: np.zeros((0, state.NX)))
    block: int = 1
    # the body's pitch compliance C (settled pitch per m/s^2, nose up accelerating) and sigma
    compliance_deg_per_mps2: float = math.nan
    compliance_sigma_deg_per_mps2: float = math.nan
    # the vertical-curve jumps the forward pass found, per block (sample i is in block
    # i // block): K's step (m/s^2 per m) and its onset that many blocks before, (0, -1) none
    jumps: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    def describe(self) -> str:
        """One line: what the smoother learnt of the odometer."""
        if not math.isfinite(self.wheel_scale):
            return "smoother: no samples"
        return (
            f"smoother: the odometer reads {100.0 * self.wheel_scale:+.2f} % "
            f"(1-sigma {100.0 * self.wheel_scale_sigma:.2f} %) of the speed (wheel diameter error)"
        )


def params(config: Config, **override: float) -> state.ModelParams:
    """The model's parameters from a bench config's estimator settings (``override``: some
    fields of :class:`~bench.fusion.model.state.ModelParams` set directly)."""
    est = config.estimator
    kw: dict[str, float] = {
        "g": config.g,
        "jerk_psd": est.accel_psd,
        "grade_psd_per_m": est.grade_psd_per_m,
        "grade_rate_psd_per_m": est.grade_rate_psd_per_m,
        "bias0_mps2": est.bias_sigma_mps2,
        "odometer_noise_mps": math.sqrt(
            est.speed_noise_mps**2 + est.speed_quantum_mps**2 / 12.0 + ODOMETER_FLOOR_MPS**2
        ),
        "channel_noise_mps2": 0.01,
        "vibration_u_mps2": 0.02,
        "vibration_w_mps2": 0.01,
    }
    kw.update(override)
    return state.ModelParams(**kw)


def channel_inputs(acc: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(y, used) of the forward pass: the readings (N, 3) with 0 where unused, and the
    channels used (bit c of ``mask`` for channel c + 1, and finite)."""
    code = np.asarray(mask, dtype=np.int64)
    n = len(code)
    y = np.array(acc, dtype=np.float64).reshape(n, 3)
    used = np.column_stack([(code >> c) & 1 for c in range(3)]).astype(np.bool_)
    used &= np.isfinite(y)
    return np.where(used, y, 0.0), used


class ModelFeed(Protocol):
    """What the estimator hands its filter's inputs to: a :class:`ModelLog` (replay), or
    the live model (bench.live.model)."""

    def add(
        self,
        b: np.ndarray,
        acc: np.ndarray,
        mask: np.ndarray,
        frames: tuple[np.ndarray, ...] | None,
        t: np.ndarray | None = None,
    ) -> None: ...


class ModelLog:
    """Keeps the estimator's inputs of a run (see :meth:`add`)."""

    def __init__(self) -> None:
        self._b: list[np.ndarray] = []
        self._acc: list[np.ndarray] = []
        self._used: list[np.ndarray] = []
        self._frames: list[tuple[np.ndarray, ...]] = []
        self.samples = 0

    def add(
        self,
        b: np.ndarray,
        acc: np.ndarray,
        mask: np.ndarray,
        frames: tuple[np.ndarray, ...] | None,
        t: np.ndarray | None = None,
    ) -> None:
        """b (N,) board time s; acc (N, 3) calibrated m/s^2; mask (N,) the channels used,
        bit c for channel c + 1; frames as the filter gets them (anchor index into this
        push, board time measured, speed m/s, restart, standstill) or None; t the samples'
        receive times (a live log's time stamps; the smoother does not need them)."""
        n = len(b)
        y, used = channel_inputs(acc, mask)
        self._b.append(np.array(b, dtype=np.float64))
        self._acc.append(y)
        self._used.append(used)
        if frames is not None and len(frames[0]):
            fa, *rest = frames
            self._frames.append((np.asarray(fa, dtype=np.int64) + self.samples, *rest))
        self.samples += n

    def smooth(self, config: Config, **override: float) -> Smoothed:
        """The forward pass and the RTS smoother over everything added."""
        prm_obj = params(config, **override)
        b = np.concatenate(self._b) if self._b else np.zeros(0)
        n = len(b)
        if n == 0:
            e = np.zeros(0)
            return Smoothed(e, e, e, e, math.nan, math.nan)
        y = np.concatenate(self._acc)
        used = np.concatenate(self._used)
        cols = list(zip(*self._frames, strict=True)) if self._frames else [()] * 5
        fa = np.concatenate(cols[0]).astype(np.int64) if self._frames else np.zeros(0, np.int64)
        fw, fs = (
            np.concatenate(c).astype(np.float64) if self._frames else np.zeros(0) for c in cols[1:3]
        )
        fr, fst = (
            np.concatenate(c).astype(np.bool_) if self._frames else np.zeros(0, np.bool_)
            for c in cols[3:5]
        )
        th = np.asarray(config.angles_rad, dtype=np.float64)
        block = max(1, int(BLOCK_S * config.sample_rate_hz))
        x0, p0 = state.initial(prm_obj)
        prm = prm_obj.array()
        accept = np.ones(len(fa), dtype=np.bool_)
        causal_x = causal_p = causal_jumps = np.zeros(0)
        for done in range(1, PASSES + 1):
            t_mid, xp, pp, xf, pf, jac, _, jumps = run.forward(
                b, y, used, fa, fw, fs, fr, fst, accept, np.cos(th), np.sin(th), prm,
                x0, p0, block, ODOMETER_GATE, CHANNEL_GATE, np.zeros(2),
                jump.hypotheses(prm_obj, BLOCK_S), 0.0, True,
            )  # fmt: skip
            if not len(causal_x):
                # the filter alone: what a live run could give
                causal_x, causal_p, causal_jumps = xf, pf, jumps
            last = done == PASSES or not len(fa)
            # a pass that only finds the slipping frames needs no smoothed covariance
            xs, ps = smoother.rts(xp, pp, xf, pf, jac, last)
            if last:
                break
            found = _consistent(fa // block, fw, fs, t_mid, xs, prm_obj.odometer_noise_mps)
            if np.array_equal(found, accept):  # another pass would repeat this one
                xs, ps = smoother.rts(xp, pp, xf, pf, jac, True)
                break
            accept = found
        idx = np.arange(n) // block
        few = used.sum(axis=1) < 2
        limit = config.gradient_sigma_limit_permil
        g = config.g
        out: list[np.ndarray] = []
        for xx, px in ((causal_x, causal_p), (xs, ps)):
            grad, sig = gradient_permil(xx[:, state.S], px[:, state.S, state.S], g)
            value, sigma = grad[idx], sig[idx]
            out += [np.where(few | ~(sigma <= limit), np.nan, value), sigma]
        return Smoothed(
            out[0],
            out[1],
            out[2],
            out[3],
            wheel_scale=float(xs[0, state.E]),
            wheel_scale_sigma=float(math.sqrt(ps[0, state.E, state.E])),
            states=xs,
            states_sigma=np.sqrt(np.maximum(np.diagonal(ps, axis1=1, axis2=2), 0.0)),
            block=block,
            compliance_deg_per_mps2=math.degrees(float(xs[0, state.C])),
            compliance_sigma_deg_per_mps2=math.degrees(math.sqrt(float(ps[0, state.C, state.C]))),
            jumps=causal_jumps,
        )


def _consistent(
    k: np.ndarray, fw: np.ndarray, fs: np.ndarray, t_mid: np.ndarray, xs: np.ndarray, sigma: float
) -> np.ndarray:
    """Per SPEED_REF frame (applied in block k, measured at board time fw, reading fs):
    within SLIP_SIGMA of what the smoothed state expects of it, and no frame within
    SLIP_MARGIN_S of it is not."""
    x = xs[k]
    age = t_mid[k] - fw + x[:, state.L]
    expect = (1.0 + x[:, state.E]) * (x[:, state.V] - age * x[:, state.A])
    off = np.abs(fs - expect) > SLIP_SIGMA * sigma
    if not off.any():
        return np.ones(len(fs), dtype=np.bool_)
    bad_t = fw[off]
    lo = np.searchsorted(bad_t, fw - SLIP_MARGIN_S, side="left")
    hi = np.searchsorted(bad_t, fw + SLIP_MARGIN_S, side="right")
    return np.asarray(hi == lo)


def gradient_permil(s: np.ndarray, var_s: np.ndarray, g: float) -> tuple[np.ndarray, np.ndarray]:
    """Gradient 1000 tan(alpha) (permil) of S = g sin(alpha) and its 1-sigma from var(S)."""
    c2 = g * g - s * s
    grad = 1000.0 * s / np.sqrt(c2)
    sig = 1000.0 * g * g / c2**1.5 * np.sqrt(np.maximum(var_s, 0.0))
    return grad, sig
