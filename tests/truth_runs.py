"""Synthetic runs with known truth for the joint filter, made directly in the pipeline's layouts.

Independent of the emulator on purpose: plain numpy physics (jerk-limited motion integrated
at 1 kHz, piecewise-linear gradient in distance, rigid-body vibration, an odometer with
quantisation, latency, noise, wheel slide and dropouts), so the filter is tested against
a truth its own code did not make.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bench.records.board import SPEED_DTYPE
from bench.records.samples import SAMPLE_DTYPE
from protocol.layout import G0, NOMINAL_SCALE

ANGLES_DEG = (30.0, 0.0, -30.0)


@dataclass
class Run:
    duration_s: float = 60.0
    rate_hz: int = 200
    v0: float = 0.0
    jerk: float = 0.8  # m/s^3; 0 = steps of acceleration
    phases: list[tuple[float, float]] = field(default_factory=list)  # (until_s, accel)
    track: list[tuple[float, float]] = field(default_factory=lambda: [(1e9, 0.0)])  # (len, permil)
    curve_m: float = 100.0
    curve_accel: bool = True  # the car feels v^2/R normal to the track on vertical curves
    noise: float = 0.0098  # 1 mg per channel
    bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    vib_long: float = 0.0  # m/s^2 at 2.5 Hz, full from 10 m/s
    vib_vert: float = 0.0
    vib_broad: float = 0.0  # broadband longitudinal (band-limited noise), m/s^2 rms
    odo_quantum: float = 0.001
    odo_noise: float = 0.0
    odo_lag: float = 0.0
    slides: list[tuple[float, float, float]] = field(default_factory=list)  # (t0, t1, depth)
    dropouts: list[tuple[float, float]] = field(default_factory=list)
    speed_ref: bool = True
    seed: int = 0


def motion(run: Run, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(accel, speed, position) on the fine time grid t (uniform)."""
    dt = t[1] - t[0]
    target = np.zeros_like(t)
    start = 0.0
    for until, a in run.phases:
        target[(t >= start) & (t < until)] = a
        start = until
    acc = np.zeros_like(t)
    v = np.zeros_like(t)
    x = np.zeros_like(t)
    a_k, v_k, x_k = 0.0, run.v0, 0.0
    step = run.jerk * dt if run.jerk > 0 else math.inf
    for i in range(len(t)):
        d = target[i] - a_k
        a_k += max(-step, min(step, d))
        if v_k <= 0.0 and a_k < 0.0:
            a_k = 0.0
        acc[i], v[i], x[i] = a_k, v_k, x_k
        v_new = v_k + a_k * dt
        if v_new < 0.0:
            v_new = 0.0
        x_k += 0.5 * (v_k + v_new) * dt
        v_k = v_new
    return acc, v, x


def gradient_at(run: Run, x: np.ndarray) -> np.ndarray:
    out = np.full_like(x, run.track[0][1])
    boundary = 0.0
    for (l0, g0), (_, g1) in zip(run.track[:-1], run.track[1:], strict=True):
        boundary += l0
        if run.curve_m > 0:
            out += (g1 - g0) * np.clip((x - boundary) / run.curve_m + 0.5, 0.0, 1.0)
        else:
            out += np.where(x >= boundary, g1 - g0, 0.0)
    return out


def slope_at(run: Run, x: np.ndarray) -> np.ndarray:
    """d(gradient)/dx, per mille per metre: each change spread evenly over its curve."""
    out = np.zeros_like(x)
    boundary = 0.0
    for (l0, g0), (_, g1) in zip(run.track[:-1], run.track[1:], strict=True):
        boundary += l0
        if run.curve_m > 0:
            out += np.where(np.abs(x - boundary) < 0.5 * run.curve_m, (g1 - g0) / run.curve_m, 0.0)
    return out


def make(run: Run) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """(samples SAMPLE_DTYPE, acc (N, 3) m/s^2, speeds SPEED_DTYPE, truth per sample)."""
    rng = np.random.default_rng(run.seed)
    fine = np.arange(0.0, run.duration_s, 0.001)
    acc, v, x = motion(run, fine)
    n = int(run.duration_s * run.rate_hz) - 1
    ts = np.arange(n) / run.rate_hz
    a_s, v_s, x_s = (np.interp(ts, fine, y) for y in (acc, v, x))
    grad = gradient_at(run, x_s)
    alpha = np.arctan(grad / 1000.0)
    scale = np.minimum(np.abs(v_s) / 10.0, 1.0)
    vib_u = run.vib_long * scale * np.sin(2 * math.pi * 2.5 * ts)
    vib_w = run.vib_vert * scale * np.sin(2 * math.pi * 2.5 * ts + 1.0)
    if run.vib_broad:
        white = rng.standard_normal(n)
        k = np.exp(-2 * math.pi * 4.0 / run.rate_hz)  # low-pass at 4 Hz, differenced below
        lp = np.zeros(n)
        for i in range(1, n):
            lp[i] = k * lp[i - 1] + (1 - k) * white[i]
        bp = np.diff(lp, prepend=0.0)  # band-pass: body motion about the bogie has no DC
        bp *= run.vib_broad / max(bp.std(), 1e-12)
        vib_u = vib_u + bp * scale
    u = a_s + vib_u + G0 * np.sin(alpha)
    w = G0 * np.cos(alpha) + vib_w
    if run.curve_accel:  # 1/R = d(alpha)/dx = (G'/1000) cos^2(alpha), towards the roof in a sag
        w = w + v_s**2 * slope_at(run, x_s) / 1000.0 * np.cos(alpha) ** 2
    th = np.radians(ANGLES_DEG)
    a_ch = u[:, None] * np.cos(th) + w[:, None] * np.sin(th) + np.array(run.bias)
    a_ch += run.noise * rng.standard_normal((n, 3))
    code = np.rint(a_ch / NOMINAL_SCALE).astype(np.int32)
    # odometer frames at 50 Hz
    tm = np.arange(0.0037, run.duration_s - 0.02, 0.02)
    keep = np.ones(len(tm), dtype=bool) if run.speed_ref else np.zeros(len(tm), dtype=bool)
    for t0, t1 in run.dropouts:
        keep &= ~((tm >= t0) & (tm < t1))
    tm = tm[keep]
    vo = np.interp(tm - run.odo_lag, fine, v)
    for t0, t1, depth in run.slides:  # sawtooth: reads low, ramps down then snaps back
        period = 1.0
        inside = (tm >= t0) & (tm < t1)
        phase = ((tm - t0) % period) / period
        vo = vo - np.where(inside, depth * np.minimum(phase / 0.7, 1.0) * (phase < 0.85), 0.0)
    vo = vo + run.odo_noise * rng.standard_normal(len(tm))
    vo = np.rint(vo / run.odo_quantum) * run.odo_quantum
    # arrival order: a sample's last frame at +0.8 ms, a speed frame at +0.4 ms
    arrive = np.concatenate([ts + 0.0008, tm + 0.0004])
    order = np.argsort(arrive, kind="stable")
    seq = np.empty(len(arrive), dtype=np.int64)
    seq[order] = np.arange(len(arrive))
    samples = np.zeros(n, dtype=SAMPLE_DTYPE)
    samples["n"] = np.arange(n)
    samples["ticks"] = np.rint(ts * 10000).astype(np.int64)
    samples["t"] = 100.0 + ts + 0.0008
    samples["seq"] = seq[:n]
    samples["code"] = code
    samples["present"] = True
    speeds = np.zeros(len(tm), dtype=SPEED_DTYPE)
    speeds["seq"] = seq[n:]
    speeds["t"] = 100.0 + tm + 0.0004
    speeds["counter"] = np.arange(len(tm)) % 256
    speeds["speed"] = np.rint(vo * 1000.0).astype(np.int32)
    speeds["timestamp"] = np.rint(tm * 10000 + 7000).astype(np.int64) % 65536
    truth = {"gradient_permil": grad, "speed_mps": v_s, "accel_mps2": a_s, "time_s": ts}
    return samples, code * NOMINAL_SCALE, speeds, truth


def push_all(est, samples, acc, speeds, batch: int = 21845):  # type: ignore[no-untyped-def]
    """Feed an Estimator in batches (frames with the push that brings them); concatenated."""
    ok = samples["present"].copy()
    owner = np.searchsorted(samples["seq"], speeds["seq"])
    outs = []
    for lo in range(0, len(samples), batch):
        sel = (owner >= lo) & (owner < lo + batch)
        out, _ = est.push(samples[lo : lo + batch], acc[lo : lo + batch], ok[lo : lo + batch],
                          speeds[sel])  # fmt: skip
        outs.append(out)
    return np.concatenate(outs)


def scores(est: np.ndarray, truth: np.ndarray, sigma: np.ndarray) -> dict[str, float]:
    """RMS, p99, max (given samples), availability, confidently wrong and 2-sigma coverage."""
    given = np.isfinite(est)
    err = np.abs(est[given] - truth[given])
    if not given.any():
        return {"rms": math.nan, "p99": math.nan, "max": math.nan, "avail": 0.0,
                "wrong": 0.0, "cover": math.nan}  # fmt: skip
    return {
        "rms": float(np.sqrt(np.mean(err**2))),
        "p99": float(np.percentile(err, 99)),
        "max": float(err.max()),
        "avail": float(given.mean()),
        "wrong": float((err > 1.0).sum() / len(est)),
        "cover": float(np.mean(err <= 2.0 * sigma[given])),
    }
