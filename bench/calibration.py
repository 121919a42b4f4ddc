"""Mounting calibration: as-built channel angles (and offsets where observable) from a recording.

Model (ICD section 3) per channel i, with a per-channel offset b_i in m/s^2:

    a_i = a * cos(theta_i) + g * sin(alpha + theta_i) + b_i

fitted by Gauss-Newton least squares to block means of the recording (blocks of
``BLOCK_S``: they average noise and vibration, and their scatter gives honest uncertainties).
Three references say what is known about a and alpha in each block:

* ``level``: standstill on level track, a = 0 and alpha = 0. Offsets are not observable
  (one pose cannot tell a tilt from an offset), so only angles are fitted, against the
  config's offsets.
* a tilt-table CSV: standstill on known gradients, one row per step
  (``start_s,end_s,gradient_permil`` on the results' time_s axis). Offsets become
  observable for pitched channels when the steps span enough gradient.
* ``speed``: in motion against SPEED_REF, as in direction-cosine calibration: a = the
  estimator's a_ref, alpha unknown per block (the track is not known) and eliminated as a
  nuisance parameter. A common pitch of the whole board is observable only through the
  train's acceleration (a*cos(theta_i) turns with the board, gravity does not), so the
  recording must accelerate and brake; blocks where a_ref is still settling after a change
  of acceleration are left out.

Offsets are fitted where the data determines them to ``OFFSET_SIGMA_MAX``; elsewhere they
stay at the config's values (and then bias the angle by about b / (g cos theta)). The
scale factors are taken from the config (a scale error s biases an angle by s * tan theta).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bench.config import ChannelCal, Config
from bench.errors import BenchError
from bench.fusion.least_squares import FULL, geometry, solve
from devices.base import SourceBatch

BLOCK_S = 0.25
"""Block length for the means the fit works on."""
MIN_FILL = 0.8
"""A block needs this fraction of its samples with all three channels usable."""
STEADY_WINDOW_S = (2.0, 0.5)
STEADY_MPS2 = 0.02
"""speed: a block is used where a_ref changed by less than this from 2 s before to 0.5 s after."""
OFFSET_SIGMA_MAX = 2e-4
"""An offset is fitted only if the data pins it to this (m/s^2, 1 sigma, about 20 ug)."""
ANGLE_SIGMA_MAX_DEG = 0.5
"""Beyond this the angles are not determined by the recording: an error, not a result."""
MAX_ITER = 50
OFFSET_NOTE_MPS2 = 9.80665e-4
"""0.1 mg: the report says what an offset this size would do to an angle."""
REFERENCES = ("speed", "level", "table")


@dataclass(frozen=True, slots=True)
class Recording:
    """What calibration needs of a replayed log, one row per sample."""

    time_s: np.ndarray  # board time from the first sample
    acc: np.ndarray  # (N, 3) calibrated with the starting config; NaN where not usable
    a_ref: np.ndarray  # estimator's reference acceleration; NaN where unavailable

    @property
    def has_speed_ref(self) -> bool:
        return bool(np.isfinite(self.a_ref).any())


@dataclass(frozen=True, slots=True)
class Fit:
    """Result of calibration."""

    reference: str  # what the recording was fitted against, in words
    angles_deg: np.ndarray  # (3,)
    angle_sigma_deg: np.ndarray  # (3,)
    offsets_mps2: np.ndarray  # (3,) change relative to the config (0 where not fitted)
    offset_sigma_mps2: np.ndarray  # (3,) NaN where not fitted
    residual_rms_mps2: float
    blocks: int
    start: Config
    config: Config  # the calibrated config

    @property
    def angles_rad(self) -> np.ndarray:
        return np.radians(self.angles_deg)

    def report(self) -> str:
        lines = [
            f"calibration against {self.reference}: {self.blocks} blocks of {BLOCK_S:g} s, "
            f"residual {self.residual_rms_mps2:.3g} m/s^2 rms"
        ]
        for i in range(3):
            old = self.start.channels[i]
            new = self.config.channels[i]
            text = (
                f"  ch{i + 1}: angle {old.angle_deg:.4f} -> {self.angles_deg[i]:.4f} deg "
                f"+/- {self.angle_sigma_deg[i]:.4f} deg"
            )
            if math.isfinite(self.offset_sigma_mps2[i]):
                text += (
                    f", offset {self.offsets_mps2[i]:+.2e} +/- {self.offset_sigma_mps2[i]:.1e} "
                    f"m/s^2 ({old.offset:.1f} -> {new.offset:.1f} LSB)"
                )
            else:
                text += f", offset not observable (kept at {old.offset:g} LSB)"
            lines.append(text)
        kept = [i for i in range(3) if not math.isfinite(self.offset_sigma_mps2[i])]
        if kept:
            shift = [
                math.degrees(OFFSET_NOTE_MPS2 / (self.start.g * math.cos(self.angles_rad[i])))
                for i in kept
            ]
            per = ", ".join(f"ch{i + 1} {d:.4f}" for i, d in zip(kept, shift, strict=True))
            lines.append(
                "  (uncertainties are statistical; 0.1 mg of offset not fitted would shift "
                f"an angle by {per} deg)"
            )
        return "\n".join(lines)


# ----------------------------------------------------------------------------- inputs


def record(batches: Iterable[SourceBatch], config: Config) -> Recording:
    """Run a stream through the bench's pipeline and keep what calibration needs."""
    from bench.pipeline.steps import Pipeline
    from bench.replay.run import run_steps

    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for step in run_steps(Pipeline(config), batches):
        r = step.results
        if len(r):
            parts.append((r["time_s"], r["acc"], r["a_ref"]))
    if not parts:
        return Recording(np.zeros(0), np.zeros((0, 3)), np.zeros(0))
    return Recording(*(np.concatenate(col) for col in zip(*parts, strict=True)))


def read_table(path: str | Path) -> np.ndarray:
    """Tilt-table steps: (K, 3) start_s, end_s, gradient_permil. One-line BenchError if bad."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise BenchError(f"cannot read table {p}: {exc.strerror or exc}") from None
    rows = []
    for lineno, row in enumerate(csv.reader(text.splitlines()), 1):
        cells = [c.strip() for c in row]
        if not cells or not cells[0] or cells[0].startswith("#"):
            continue
        if cells[0] == "start_s" and not rows:  # the header
            continue
        try:
            values = [float(c) for c in cells]
        except ValueError:
            raise BenchError(
                f"{p}:{lineno}: expected numbers start_s,end_s,gradient_permil, got {row!r}"
            ) from None
        if len(values) != 3 or not all(map(math.isfinite, values)):
            raise BenchError(f"{p}:{lineno}: expected three finite numbers, got {row!r}")
        start, end, grad = values
        if end <= start:
            raise BenchError(f"{p}:{lineno}: end_s {end:g} must be after start_s {start:g}")
        if abs(grad) > 500.0:
            raise BenchError(f"{p}:{lineno}: gradient_permil {grad:g} is outside +/-500")
        rows.append(values)
    if not rows:
        raise BenchError(f"{p}: no steps (expected rows start_s,end_s,gradient_permil)")
    return np.array(rows, dtype=np.float64)


def block_means(rec: Recording, keep: np.ndarray) -> tuple[np.ndarray, ...]:
    """Means per BLOCK_S block of the kept samples with all channels usable.

    Returns (block ids, mean acc (B, 3), mean a_ref (B,)) for blocks filled to MIN_FILL."""
    rate = 1.0 / float(np.median(np.diff(rec.time_s))) if len(rec.time_s) > 1 else 0.0
    ok = keep & np.isfinite(rec.acc).all(axis=1)
    block = np.floor(rec.time_s[ok] / BLOCK_S).astype(np.int64)
    ids, inverse, counts = np.unique(block, return_inverse=True, return_counts=True)
    acc = np.zeros((len(ids), 3))
    for k in range(3):
        acc[:, k] = np.bincount(inverse, rec.acc[ok, k], len(ids)) / counts
    a_ref = np.bincount(inverse, np.nan_to_num(rec.a_ref[ok]), len(ids)) / counts
    full = counts >= MIN_FILL * BLOCK_S * rate
    return ids[full], acc[full], a_ref[full]


def steady(rec: Recording) -> np.ndarray:
    """Samples in blocks where a_ref is available and settled: it varies by less than
    STEADY_MPS2 from STEADY_WINDOW_S[0] before the block to STEADY_WINDOW_S[1] after it
    (the causal filter needs a moment to follow a change of acceleration)."""
    if len(rec.time_s) == 0:
        return np.zeros(0, dtype=bool)
    fin = np.isfinite(rec.a_ref)
    block = np.floor(rec.time_s / BLOCK_S).astype(np.int64)
    idx = block - block.min()
    nb = int(idx.max()) + 1
    hi = np.full(nb, -np.inf)
    lo = np.full(nb, np.inf)
    np.maximum.at(hi, idx[fin], rec.a_ref[fin])
    np.minimum.at(lo, idx[fin], rec.a_ref[fin])
    bad = np.bincount(idx[~fin], minlength=nb) > 0
    bad |= np.bincount(idx, minlength=nb) == 0
    before = round(STEADY_WINDOW_S[0] / BLOCK_S)
    after = round(STEADY_WINDOW_S[1] / BLOCK_S)
    w_hi, w_lo, w_bad = hi.copy(), lo.copy(), bad.copy()
    for shift in range(-after, before + 1):  # block k looks at blocks k - before .. k + after
        if shift == 0:
            continue
        src = slice(max(-shift, 0), nb - max(shift, 0))
        dst = slice(max(shift, 0), nb - max(-shift, 0))
        w_hi[dst] = np.maximum(w_hi[dst], hi[src])
        w_lo[dst] = np.minimum(w_lo[dst], lo[src])
        w_bad[dst] |= bad[src]
    w_bad[:before] = True  # a window cut by the start of the recording is not known steady
    w_bad[nb - after :] = True
    ok = ~w_bad & (w_hi - w_lo < STEADY_MPS2)
    return ok[idx]


# -------------------------------------------------------------------------------- fit


class Undetermined(Exception):
    """The normal equations are singular: the data does not determine the parameters."""


def _solve(
    m: np.ndarray,
    a: np.ndarray,
    alpha: np.ndarray,
    free_alpha: bool,
    g: float,
    theta: np.ndarray,
    fit_offset: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Gauss-Newton for theta (3) and the offsets marked in fit_offset; alpha per block is a
    nuisance (eliminated by projection) when free_alpha.

    Returns (theta, offsets (3,), covariance of the parameters, rms residual)."""
    nb = len(m)
    off_idx = np.flatnonzero(fit_offset)
    n_par = 3 + len(off_idx)
    theta = theta.copy()
    b = np.zeros(3)
    alpha = alpha.copy()
    jac = np.zeros((nb, 3, n_par))
    for _ in range(MAX_ITER):
        phi = alpha[:, None] + theta[None, :]
        r = m - (a[:, None] * np.cos(theta) + g * np.sin(phi) + b)
        for i in range(3):
            jac[:, i, i] = -a * np.sin(theta[i]) + g * np.cos(phi[:, i])
        for col, i in enumerate(off_idx):
            jac[:, i, 3 + col] = 1.0
        jp, rp = jac, r
        if free_alpha:
            c = g * np.cos(phi)
            cn = c / np.linalg.norm(c, axis=1, keepdims=True)
            jp = jac - cn[:, :, None] * np.einsum("ji,jip->jp", cn, jac)[:, None, :]
            rp = r - cn * np.einsum("ji,ji->j", cn, r)[:, None]
        normal = np.einsum("jip,jiq->pq", jp, jp)
        rhs = np.einsum("jip,ji->p", jp, rp)
        try:
            step = np.linalg.solve(normal, rhs)
        except np.linalg.LinAlgError:
            raise Undetermined from None
        if free_alpha:
            resid = r - np.einsum("jip,p->ji", jac, step)
            alpha = alpha + np.einsum("ji,ji->j", c, resid) / np.einsum("ji,ji->j", c, c)
        theta = theta + step[:3]
        b[off_idx] += step[3:]
        if np.max(np.abs(step)) < 1e-13:
            break
    phi = alpha[:, None] + theta[None, :]
    r = m - (a[:, None] * np.cos(theta) + g * np.sin(phi) + b)
    dof = 3 * nb - n_par - (nb if free_alpha else 0)
    if dof <= 0:
        raise BenchError(f"calibration: {nb} blocks are too few to fit {n_par} parameters")
    rss = float(np.sum(r * r))
    try:
        cov = np.linalg.inv(normal) * (rss / dof)
    except np.linalg.LinAlgError:
        raise Undetermined from None
    return theta, b, cov, math.sqrt(rss / (3 * nb))


def calibrate(
    rec: Recording, config: Config, reference: str, table: np.ndarray | None = None
) -> Fit:
    """Fit the angles (and observable offsets) of ``config``'s board to a recording.

    reference: "speed", "level" or "table" (then ``table`` from :func:`read_table`)."""
    if reference not in REFERENCES:
        raise BenchError(f"calibration: unknown reference {reference!r} (speed, level or table)")
    if reference == "table" and table is None:
        raise BenchError("calibration: the table reference needs a table of steps")
    if len(rec.time_s) == 0:
        raise BenchError("calibration: the recording has no samples")
    if reference == "speed" and not rec.has_speed_ref:
        raise BenchError(
            "calibration: no SPEED_REF in the recording; use --reference level or a table"
        )
    n = len(rec.time_s)
    standstill = rec.a_ref == 0.0 if rec.has_speed_ref else np.ones(n, dtype=bool)
    if reference == "speed":
        keep = steady(rec)
        name = "SPEED_REF (in motion)"
    elif reference == "level":
        keep = standstill
        name = "level track at standstill"
    else:
        assert table is not None
        keep = np.zeros(n, dtype=bool)
        for start, end, _ in table:
            keep |= (rec.time_s >= start) & (rec.time_s < end)
        keep &= standstill
        name = f"tilt-table steps ({len(table)})"
    ids, m, a = block_means(rec, keep)
    if len(ids) < 2:
        raise BenchError(f"calibration: too little usable data against the {name}")
    g = config.g
    theta0 = np.asarray(config.angles_rad, dtype=np.float64)
    if reference == "speed":  # start each block's gradient where the starting angles put it
        u, w = solve(m, np.full(len(m), FULL), geometry(theta0))
        alpha = np.arctan2(u - a, w)
    elif reference == "level":
        a = np.zeros(len(ids))
        alpha = np.zeros(len(ids))
    else:
        assert table is not None
        a = np.zeros(len(ids))
        centre = (ids + 0.5) * BLOCK_S
        row = np.clip(np.searchsorted(table[:, 0], centre, side="right") - 1, 0, None)
        alpha = np.arctan(table[row, 2] / 1000.0)
    fit_offset = np.full(3, reference != "level")
    hint = "; it needs more acceleration and braking" if reference == "speed" else ""
    while True:
        try:
            theta, b, cov, rms = _solve(m, a, alpha, reference == "speed", g, theta0, fit_offset)
        except Undetermined:
            if fit_offset.any():  # offsets first: they are the usual reason
                fit_offset[:] = False
                continue
            raise BenchError(
                f"calibration: the recording does not determine the angles{hint}"
            ) from None
        sig = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        off_sig = np.full(3, np.nan)
        off_sig[fit_offset] = sig[3:]
        weak = fit_offset & ~(off_sig <= OFFSET_SIGMA_MAX)
        if not weak.any():
            break
        fit_offset &= ~weak  # not determined by the data: keep the config's, fit again
    angle_sig = np.degrees(sig[:3])
    if not (angle_sig <= ANGLE_SIGMA_MAX_DEG).all():
        worst = float(np.max(angle_sig))
        raise BenchError(
            f"calibration: the recording does not determine the angles "
            f"(uncertainty {worst:.2g} deg){hint}"
        )
    channels = []
    for i, ch in enumerate(config.channels):
        offset = ch.offset + b[i] / ch.scale  # code offset in LSB: a = (code - offset) * scale
        channels.append(ChannelCal(float(np.degrees(theta[i])), ch.scale, float(offset)))
    new = replace(config, channels=tuple(channels), source="calibration")  # type: ignore[arg-type]
    return Fit(
        reference=name,
        angles_deg=np.degrees(theta),
        angle_sigma_deg=angle_sig,
        offsets_mps2=b,
        offset_sigma_mps2=off_sig,
        residual_rms_mps2=rms,
        blocks=len(ids),
        start=config,
        config=new,
    )
