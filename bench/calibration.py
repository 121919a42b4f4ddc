"""Mounting calibration: as-built channel angles (and offsets where observable) from a recording.

Model (ICD section 3) per channel i, with a per-channel offset b_i in m/s^2:

    a_i = a * cos(theta_i) + g * sin(alpha + theta_i) + c * sin(theta_i) + b_i

fitted by Gauss-Newton least squares to block means of the recording (blocks of
``BLOCK_S``: they average noise and vibration), where c is the car's acceleration normal to
the track (the v^2/R of a vertical curve; 0 at standstill and on a constant grade). Three
references say what is known about a, alpha and c in each block:

* ``level``: standstill on level track, a = 0, alpha = 0, c = 0. Offsets are not observable
  (one pose cannot tell a tilt from an offset), so only angles are fitted, against the
  config's offsets.
* a tilt-table CSV: standstill on known gradients, one row per step
  (``start_s,end_s,gradient_permil`` on the results' time_s axis). Offsets become
  observable for pitched channels when the steps span enough gradient.
* ``speed``: in motion against SPEED_REF, as in direction-cosine calibration: a is the
  odometer's acceleration (a centred derivative of the SPEED_REF speed, computed here, so
  it does not lag), alpha unknown per block (the track is not known) and eliminated as a
  nuisance parameter, and c = v^2 * d(alpha)/dx with d(alpha)/dx the slope of the fitted
  alphas against the distance travelled (a local regression over ``CURVE_WINDOW_M``),
  iterated with the fit. A common pitch of the whole board is observable only through the
  train's acceleration (a*cos(theta_i) turns with the board, gravity does not), so the
  recording must accelerate and brake; blocks where the acceleration is changing (a ramp,
  a wheel-slide cycle, a SPEED_REF gap) are left out, and the block weights taper over
  ``TAPER_S`` at each edge of a run of used blocks, so that the car body's vibration
  cannot leak into the fit through hard edges.

The stated uncertainties come from the scatter of the blocks' residuals with their
correlation in time accounted for (a Newey-West estimate over ``HAC_S``): vibration, the
odometer's noise through a and c, and what the curve model leaves are correlated over
seconds, so independent-block statistics would understate them.

Offsets are fitted where the data determines them to ``OFFSET_SIGMA_MAX``; elsewhere they
stay at the config's values (and then bias the angle by about b / (g cos theta)). The
scale factors are taken from the config (a scale error s biases an angle by s * tan theta).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
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
STEADY_S = 1.5
STEADY_BIN_S = 0.05
STEADY_JERK_MPS3 = 0.05
STEADY_RESIDUAL_MPS = 0.03
"""speed: a block is used where a parabola through the odometer's speeds over STEADY_S on
each side has a jerk below this and leaves this rms (:func:`steady`)."""
LOAD_SETTLE_S = 1.5
LOAD_GUARD_S = 1.5
LOAD_WINDOW_S = 1.5
LOAD_EDGE = 0.15
"""The body's static pitch changes at stops (:func:`load_pitch`): measured from LOAD_SETTLE_S
after the stop and until LOAD_GUARD_S before the departure, means over LOAD_WINDOW_S but
within LOAD_EDGE of the stop's length from each end."""
FROZEN_SAMPLES = 5
"""A channel whose code repeats over this many samples while another's changes is stuck
(:func:`frozen`): with any noise a 24-bit code repeats from one sample to the next about
once in a thousand samples, five times in a row never."""
TEMPCO_SIGMA = 1e-4
TEMPCO_MIN_K = 2.0
"""speed: where the board's temperature (BOARD_STATUS) spans at least TEMPCO_MIN_K over the
used blocks, each channel's offset is fitted to move linearly with it, prior 0 +/-
TEMPCO_SIGMA m/s^2 per K (10 ug/K: the tempco a sheet taken at one temperature cannot
know; 30 K of it would turn an angle by 0.02 deg and the channels apart). The fitted
offsets are those at the first used block's temperature."""
MIN_ACCEL_S = 5.0
MIN_ACCEL_MPS2 = 0.1
"""speed: the steady blocks must hold this much time (taper-weighted) of acceleration or
braking of at least MIN_ACCEL_MPS2, or the common pitch is not determined: a few blocks
of it are fitted as exactly as they are noisy, so their residuals cannot say how wrong
the angles are (a run of 0.1 s of steady braking came out 1.6 deg off at a stated 0.26)."""
ACCEL_WINDOW_S = 0.5
"""The odometer's acceleration: slope of a straight line through its speeds within this of
each frame, both sides (a centred derivative: no lag, noise averaged over 1 s)."""
ODOMETER_GAP_S = 0.2
"""SPEED_REF frames further apart than this (50 Hz: 0.02 s) leave the speed unknown between."""
CURVE_WINDOW_M = 20.0
CURVE_WINDOW_S = 2.0
"""c = v^2 d(alpha)/dx: the slope of the fitted alphas over this much track on each side, or
over the distance run in CURVE_WINDOW_S if longer."""
CURVE_SIGNIFICANCE = 4.0
"""... kept where it exceeds this many of its own sigmas (else the track counts as straight)."""
CURVE_ITER = 6
CURVE_MODEL_SHARE = 0.3
"""The modelled c counts as known to this share of the largest c nearby (1 sigma)."""
TAPER_S = 1.0
"""Block weights rise over this at each edge of a run of used blocks (a cosine taper)."""
SCATTER_S = 4.0
"""The blocks are weighted by 1 / their residuals' power over this on each side."""
HAC_S = 16.0
"""Correlation time the uncertainty allows for (Bartlett-weighted lags up to this)."""
WHEEL_ERROR_SIGMA = 0.03 / math.sqrt(3.0)
"""The odometer's wheel-diameter error e (SPEED_REF = true speed * (1 + e)) before the fit:
uniform within +/-3 % (a worn or wrongly configured wheel), 1 sigma. It scales the
reference acceleration, so it turns the board like a common pitch of about e * sin(alpha)
wherever the train accelerates on a grade. Not fitted (the random runs hardly determine it:
fitted, it came out near 0 whatever it was): in motion the uncertainties count what it
would move the angles by."""
COMPLIANCE_DEG_PER_MPS2 = (0.1, 0.1)
"""The car body's pitch on its secondary suspension per m/s^2 of the train's acceleration
(nose up accelerating), before the fit: h / (w_b^2 b^2) for a body's centre of gravity h
above the traction rods, bounce frequency w_b and bogie centres at +/- b: 0.05 deg for a
metro car (h 1.2 m, 1 Hz, 6 m; docs/EMULATOR.md), up to about 0.2 for a soft or short one
(issue 25). Mean and 1 sigma; in motion it is fitted with this as its prior."""
COMPLIANCE_RAD = math.radians(COMPLIANCE_DEG_PER_MPS2[0])
COMPLIANCE_SIGMA_RAD = math.radians(COMPLIANCE_DEG_PER_MPS2[1])
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
    a_ref: np.ndarray  # the odometer's acceleration (odometer_accel); NaN where unknown
    speed_mps: np.ndarray | None = None  # the latest SPEED_REF speed; NaN where unknown
    temperature_c: np.ndarray | None = None  # BOARD_STATUS's, smoothed (board_temperature)

    @property
    def has_speed_ref(self) -> bool:
        return bool(np.isfinite(self.a_ref).any())

    @property
    def speed(self) -> np.ndarray:
        if self.speed_mps is None:
            return np.where(self.a_ref == 0.0, 0.0, np.nan)
        return self.speed_mps


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
    compliance_deg_per_mps2: float = 0.0  # the body's fitted pitch per m/s^2 (speed only)
    compliance_sigma: float = math.nan  # its 1 sigma (deg per m/s^2); NaN where not fitted

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
        if math.isfinite(self.compliance_sigma):
            lines.append(
                f"  car body: pitch {self.compliance_deg_per_mps2:+.3f} "
                f"+/- {self.compliance_sigma:.3f} deg per m/s^2 of acceleration (nose up); "
                f"the odometer's wheel counted as +/-{100 * WHEEL_ERROR_SIGMA:.1f} % of scale"
            )
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
    """Run a stream through the bench's pipeline and keep what calibration needs: the
    calibrated channels per sample, and the SPEED_REF frames' speeds, each placed at the
    first sample that arrived after it (:func:`odometer_accel`)."""
    from bench.pipeline.steps import Pipeline
    from bench.replay.run import run_steps

    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    speeds: list[tuple[np.ndarray, np.ndarray]] = []
    temps: list[tuple[np.ndarray, np.ndarray]] = []
    for step in run_steps(Pipeline(config), batches):
        r = step.results
        if len(r):
            parts.append((r["time_s"], r["acc"], r["seq"], r["code"]))
        if len(step.speed):
            speeds.append((step.speed["seq"], step.speed["speed"] / 1000.0))
        if len(step.status):
            temps.append((step.status["seq"], step.status["temperature"].astype(np.float64)))
    if not parts:
        return Recording(np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    time_s, acc, seq, code = (np.concatenate(col) for col in zip(*parts, strict=True))
    acc = np.where(frozen(code), np.nan, acc)
    if speeds:
        odo_seq, odo_v = (np.concatenate(col) for col in zip(*speeds, strict=True))
    else:
        odo_seq, odo_v = np.zeros(0, np.int64), np.zeros(0)
    a, v = odometer_accel(time_s, seq, odo_seq, odo_v)
    temperature = None
    if temps:
        st_seq, st_t = (np.concatenate(col) for col in zip(*temps, strict=True))
        anchor = np.searchsorted(seq, st_seq, side="right")
        keep = anchor < len(seq)
        if keep.any():
            temperature = board_temperature(time_s[anchor[keep]], st_t[keep], time_s)
    return Recording(time_s, acc, a, v, temperature)


def board_temperature(t: np.ndarray, whole_c: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The board's temperature at times ``at`` from BOARD_STATUS's whole degrees (at times
    ``t``): where the reading changes the temperature is passing between the two values,
    so a line through those crossings (their midpoints) undoes the 1 K steps of a slowly
    changing temperature; held flat before the first and after the last."""
    change = np.flatnonzero(np.diff(whole_c) != 0) + 1
    if not len(change):
        return np.full(len(at), float(whole_c[0]))
    tc = 0.5 * (t[change - 1] + t[change])
    vc = 0.5 * (whole_c[change - 1] + whole_c[change])
    out: np.ndarray = np.interp(at, tc, vc)
    return out


def frozen(code: np.ndarray) -> np.ndarray:
    """(N, 3) True where a channel's ADC code stays the same over FROZEN_SAMPLES or more
    consecutive samples while another channel's code changes within them: a stuck
    channel, from its first frozen sample on. The estimator's own stuck test says so only
    after its window, and the stale value it kept until then is what a calibration must
    not see: at a stand where passengers board, a channel stuck for 9 s read 0.01 m/s^2
    stale, and the quiet standing blocks, the most weighted, turned the fit 0.46 deg."""
    n = len(code)
    out = np.zeros(code.shape, dtype=bool)
    if n < 2:
        return out
    changed = np.diff(code, axis=0) != 0  # (N - 1, 3): sample i + 1 differs from i
    for k in range(code.shape[1]):
        others = np.cumsum(
            np.concatenate([[0], changed[:, [j for j in range(3) if j != k]].any(axis=1)])
        )
        same = ~changed[:, k]
        edges = np.diff(np.concatenate([[0], same.astype(np.int8), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # diff rows
        for s0, e0 in zip(starts, ends, strict=True):  # samples s0 .. e0 share one code
            if e0 - s0 + 1 >= FROZEN_SAMPLES and others[e0] > others[s0]:
                out[s0 : e0 + 1, k] = True
    return out


def window_sums(
    columns: tuple[np.ndarray, ...], lo: np.ndarray, hi: np.ndarray
) -> list[np.ndarray]:
    """Per row k, the sum of each column over rows lo[k] .. hi[k] - 1 (prefix sums): the
    moments of a sliding least-squares line."""
    out = []
    for x in columns:
        c = np.concatenate([[0.0], np.cumsum(x)])
        out.append(c[hi] - c[lo])
    return out


def odometer_accel(
    time_s: np.ndarray, seq: np.ndarray, odo_seq: np.ndarray, odo_v: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(acceleration, speed) per sample from the SPEED_REF frames (arrival indices
    ``odo_seq``, speeds ``odo_v`` in m/s) and the samples' board times and arrival indices.

    A frame counts at the board time of the first sample whose last frame arrived after
    it. Its acceleration is the slope of a least-squares line through the speeds within
    ACCEL_WINDOW_S of it on both sides (it needs frames on both sides and no gap longer
    than ODOMETER_GAP_S inside; exactly 0 where they all read 0). A sample takes the
    latest frame's speed and the acceleration interpolated between frames; NaN where
    unknown (before the first frame, in a gap)."""
    n = len(time_s)
    nan = np.full(n, np.nan)
    anchor = np.searchsorted(seq, odo_seq, side="right")
    keep = anchor < n
    tau, v = time_s[anchor[keep]], odo_v[keep]
    m = len(tau)
    if m < 3:
        return nan, nan.copy()
    idx = np.arange(m)
    lo = np.searchsorted(tau, tau - ACCEL_WINDOW_S, side="left")
    hi = np.searchsorted(tau, tau + ACCEL_WINDOW_S, side="right")
    t0 = tau - tau[0]
    s1, st, sv, stt, stv = window_sums((np.ones(m), t0, v, t0 * t0, t0 * v), lo, hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = (stv - st * sv / s1) / (stt - st * st / s1)
    after_gap = np.flatnonzero(np.diff(tau) > ODOMETER_GAP_S) + 1  # frames that follow a gap
    broken = (
        np.searchsorted(after_gap, hi, side="left") - np.searchsorted(after_gap, lo, side="right")
    ) > 0
    both = (lo < idx) & (hi > idx + 1)
    (absolute,) = window_sums((np.abs(v),), lo, hi)
    standing = absolute == 0.0
    good = both & ~broken & np.isfinite(slope)
    a_frame = np.where(standing, 0.0, np.where(good, slope, np.nan))
    k = np.searchsorted(tau, time_s, side="right") - 1  # the latest frame at each sample
    kk = np.clip(k, 0, m - 1)
    nxt = np.minimum(kk + 1, m - 1)
    fresh = (k >= 0) & (time_s - tau[kk] <= ODOMETER_GAP_S)
    span = tau[nxt] - tau[kk]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(span > 0, np.clip((time_s - tau[kk]) / span, 0.0, 1.0), 0.0)
    accel = np.where(fresh, a_frame[kk] * (1.0 - w) + a_frame[nxt] * w, np.nan)
    return accel, np.where(fresh, v[kk], np.nan)


def read_table(path: str | Path) -> np.ndarray:
    """Tilt-table steps: (K, 3) start_s, end_s, gradient_permil. One-line BenchError if bad."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")  # an editor's byte-order mark is fine
    except OSError as exc:
        raise BenchError(f"cannot read table {p}: {exc.strerror or exc}") from None
    rows: list[list[float]] = []
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


@dataclass(frozen=True, slots=True)
class Blocks:
    """Means per BLOCK_S block (only blocks filled to MIN_FILL with usable samples)."""

    ids: np.ndarray  # block index: floor(time_s / BLOCK_S)
    acc: np.ndarray  # (B, 3) mean calibrated acceleration per channel
    a: np.ndarray  # mean odometer acceleration
    v2: np.ndarray  # mean squared speed
    x: np.ndarray  # mean distance travelled since the start (m)
    temp: np.ndarray  # mean board temperature (degC); NaN where unknown


def block_means(rec: Recording, keep: np.ndarray) -> Blocks:
    """Means per BLOCK_S block of the kept samples with all channels usable."""
    rate = 1.0 / float(np.median(np.diff(rec.time_s))) if len(rec.time_s) > 1 else 0.0
    speed = np.nan_to_num(rec.speed)
    dt = np.diff(rec.time_s, prepend=rec.time_s[:1])
    x = np.cumsum(speed * dt)
    ok = keep & np.isfinite(rec.acc).all(axis=1)
    block = np.floor(rec.time_s[ok] / BLOCK_S).astype(np.int64)
    ids, inverse, counts = np.unique(block, return_inverse=True, return_counts=True)

    def mean(values: np.ndarray) -> np.ndarray:
        return np.bincount(inverse, values, len(ids)) / counts

    acc = (
        np.column_stack([mean(rec.acc[ok, k]) for k in range(3)]) if len(ids) else np.zeros((0, 3))
    )
    full = counts >= MIN_FILL * BLOCK_S * rate
    return Blocks(
        ids[full],
        acc[full],
        mean(np.nan_to_num(rec.a_ref[ok]))[full],
        mean(speed[ok] ** 2)[full],
        mean(x[ok])[full],
        mean(rec.temperature_c[ok])[full]
        if rec.temperature_c is not None
        else np.full(int(full.sum()), np.nan),
    )


def steady(rec: Recording) -> np.ndarray:
    """Samples in blocks where the train's acceleration is known and steady: a parabola
    through the odometer's speeds over STEADY_S on each side of the block (on a grid of
    STEADY_BIN_S means, every bin known) has a jerk below STEADY_JERK_MPS3 (then its
    latency, up to 0.1 s, costs < 0.005 m/s^2 of acceleration) and leaves speeds within
    STEADY_RESIDUAL_MPS rms (not a ramp of traction or braking, a wheel-slide or slip
    cycle, a SPEED_REF gap). A parabola over 3 s, not the spread of the per-frame slopes,
    is what tells a ramp from the odometer's own noise: a 50 mm/s odometer's 1 s slopes
    scatter by 0.02 m/s^2 while its 3 s jerk is known to 0.006 m/s^3."""
    n = len(rec.time_s)
    if n == 0:
        return np.zeros(0, dtype=bool)
    speed = rec.speed
    t = rec.time_s
    bins = np.floor((t - t[0]) / STEADY_BIN_S).astype(np.int64)
    nbin = int(bins[-1]) + 1
    fin = np.isfinite(speed)
    count = np.bincount(bins, minlength=nbin)
    known = np.bincount(bins[fin], minlength=nbin)
    total = np.bincount(bins[fin], speed[fin], minlength=nbin)
    full = (count > 0) & (known == count)
    v = np.where(full, total / np.maximum(known, 1), 0.0)
    half = round(STEADY_S / STEADY_BIN_S)
    u = np.arange(-half, half + 1) * STEADY_BIN_S
    basis = np.vstack([np.ones_like(u), u, u * u])  # (3, L)
    filters = np.linalg.solve(basis @ basis.T, basis)  # LS coefficients as fixed filters
    coef = np.array([np.convolve(v, f[::-1], "same") for f in filters])  # (3, nbin)
    power = np.convolve(v * v, np.ones(len(u)), "same")
    explained = sum(coef[i] * np.convolve(v, basis[i][::-1], "same") for i in range(3))
    resid_rms = np.sqrt(np.maximum(power - explained, 0.0) / len(u))
    missing = np.convolve((~full).astype(np.float64), np.ones(len(u)), "same") > 0.5
    edge = np.zeros(nbin, dtype=bool)
    edge[:half] = True  # a window cut by the start or end of the recording is not known
    edge[nbin - half :] = True
    ok_bin = (
        ~missing
        & ~edge
        & (np.abs(2.0 * coef[2]) < STEADY_JERK_MPS3)
        & (resid_rms < STEADY_RESIDUAL_MPS)
    )
    # a block is steady when every bin it touches is
    block = np.floor(t / BLOCK_S).astype(np.int64)
    idx = block - block.min()
    nb = int(idx.max()) + 1
    bad = np.bincount(idx, (~ok_bin[bins]).astype(np.float64), minlength=nb) > 0
    bad |= np.bincount(idx[~np.isfinite(rec.a_ref)], minlength=nb) > 0
    return ~bad[idx]


# -------------------------------------------------------------------------------- fit


class Undetermined(Exception):
    """The normal equations are singular: the data does not determine the parameters."""


@dataclass(frozen=True, slots=True)
class Solution:
    """What :func:`_solve` found: the parameters, their covariance (theta, fitted offsets,
    then C where fitted), the blocks' alphas and unweighted residuals (B, 3)."""

    theta: np.ndarray
    b: np.ndarray
    cov: np.ndarray
    rms: float
    alpha: np.ndarray
    resid: np.ndarray
    compliance: float = 0.0  # rad per m/s^2
    c_col: int | None = None
    tempco: np.ndarray = field(default_factory=lambda: np.zeros(3))  # m/s^2 per K
    d_col: int | None = None


def _solve(
    m: np.ndarray,
    a: np.ndarray,
    alpha: np.ndarray,
    free_alpha: bool,
    g: float,
    theta: np.ndarray,
    fit_offset: np.ndarray,
    normal_accel: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    ids: np.ndarray | None = None,
    normal_sigma: np.ndarray | None = None,
    scale_sigma: float | None = None,
    compliance: tuple[float, float] | None = None,
    pitch: np.ndarray | None = None,
    pitch_steps: list[tuple[int, float]] | None = None,
    temperature: np.ndarray | None = None,
) -> Solution:
    """Gauss-Newton for theta (3) and the offsets marked in fit_offset; alpha per block is a
    nuisance (eliminated by projection) when free_alpha; ``normal_accel`` (c per block) is
    known. ``weights`` weigh the blocks; with ``ids`` (block indices in time) the
    covariance counts the residuals' correlation over HAC_S (Newey-West), else it takes
    them as independent, and ``normal_sigma`` (1 sigma of c per block, correlated like
    the residuals) adds what an error of c would move the parameters by.

    Two nuisances of a moving car. With ``compliance`` = (mean, sigma) the car body's
    pitch on its suspension, beta = C * a (rad, C in rad per m/s^2), is fitted: it turns
    every sensor's axis to theta_i + beta, which a common pitch of the board cannot tell
    from the board unless the acceleration takes more than one value. Its prior is a
    pseudo-measurement in the normal equations (the fit is the posterior's mode) and in
    the covariance's sandwich, so that where the recording does not determine C it keeps
    its prior's sigma and passes it on to the angles through their correlation with it.
    With ``temperature`` (per block, K from a reference) each channel's offset moves by
    its own tempco times it, fitted with the prior 0 +/- TEMPCO_SIGMA. ``pitch`` is the
    body's static pitch per block (rad, known: :func:`load_pitch`), and
    ``pitch_steps`` its changes, (first block after, 1 sigma), whose uncertainty the
    covariance adds. With ``scale_sigma`` the reference's scale k (true a and c = k *
    given, k = 1 +/- scale_sigma) is not fitted but considered: the covariance adds what it
    would move the parameters by.
    """
    nb = len(m)
    off_idx = np.flatnonzero(fit_offset)
    n_par = 3 + len(off_idx)
    c_col = d_col = None
    priors: list[tuple[int, float, float]] = []  # (column, mean, sigma)
    if temperature is not None:
        d_col, n_par = n_par, n_par + 3
        priors += [(d_col + i, 0.0, TEMPCO_SIGMA) for i in range(3)]
    if compliance is not None:
        c_col, n_par = n_par, n_par + 1
        priors.append((c_col, compliance[0], compliance[1]))
    c = np.zeros(nb) if normal_accel is None else normal_accel
    lp = np.zeros(nb) if pitch is None else pitch
    sw = np.ones(nb) if weights is None else np.sqrt(weights)
    x = np.zeros(n_par)
    x[:3] = theta
    for col, mean, _ in priors:
        x[col] = mean
    alpha = alpha.copy()
    jac = np.zeros((nb, 3, n_par))
    dof = 3 * nb - n_par - (nb if free_alpha else 0)
    if dof <= 0:
        raise BenchError(f"calibration: {nb} blocks are too few to fit {n_par} parameters")

    def unpack(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """theta, the offsets per block (B, 3) or (3,), C."""
        b = np.zeros(3)
        b[off_idx] = x[3 : 3 + len(off_idx)]
        if d_col is not None:
            assert temperature is not None
            b = b + temperature[:, None] * x[d_col : d_col + 3]
        return x[:3], b, float(x[c_col]) if c_col is not None else 0.0

    def model(alpha: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(weighted residuals, d(pred)/d(axis angle), d(pred)/d(alpha)), each (B, 3)."""
        th, b, cc = unpack(x)
        psi = th[None, :] + (cc * a + lp)[:, None]  # each axis on the pitched body
        phi = alpha[:, None] + psi
        aa, ca = a[:, None], c[:, None]
        pred = aa * np.cos(psi) + ca * np.sin(psi) + g * np.sin(phi) + b
        d_psi = -aa * np.sin(psi) + ca * np.cos(psi) + g * np.cos(phi)
        return (m - pred) * sw[:, None], d_psi, g * np.cos(phi)

    def project(v: np.ndarray, gn: np.ndarray) -> np.ndarray:
        """Remove each block's component along its gravity direction (alpha's column)."""
        if v.ndim == 3:
            return v - gn[:, :, None] * np.einsum("ji,jip->jp", gn, v)[:, None, :]
        return v - gn * np.einsum("ji,ji->j", gn, v)[:, None]

    hold = np.zeros((n_par, n_par))  # the priors' information, in units of the residuals'
    step = np.zeros(n_par)
    for _ in range(MAX_ITER):
        r, d_psi, d_alpha = model(alpha, x)
        for i in range(3):
            jac[:, i, i] = d_psi[:, i] * sw
        for col, i in enumerate(off_idx.tolist()):
            jac[:, i, 3 + col] = sw
        if d_col is not None:
            assert temperature is not None
            for i in range(3):
                jac[:, i, d_col + i] = temperature * sw
        if c_col is not None:
            jac[:, :, c_col] = d_psi * (a * sw)[:, None]
        jp, rp = jac, r
        grav = d_alpha * sw[:, None]
        gn = grav / np.linalg.norm(grav, axis=1, keepdims=True)
        if free_alpha:
            jp, rp = project(jac, gn), project(r, gn)
        normal = np.einsum("jip,jiq->pq", jp, jp)
        rhs = np.einsum("jip,ji->p", jp, rp)
        if priors:
            sigma2 = float(np.sum(rp * rp)) / dof  # the residuals' variance, for the holds
            for col, mean, sigma in priors:
                hold[col, col] = sigma2 / sigma**2
                rhs[col] -= hold[col, col] * (x[col] - mean)
            normal = normal + hold
        try:
            step = np.linalg.solve(normal, rhs)
        except np.linalg.LinAlgError:
            raise Undetermined from None
        if free_alpha:
            resid = r - np.einsum("jip,p->ji", jac, step)
            alpha = alpha + np.einsum("ji,ji->j", grav, resid) / np.einsum("ji,ji->j", grav, grav)
        x = x + step
        if np.max(np.abs(step)) < 1e-13:
            break
    else:
        if np.max(np.abs(step)) > 1e-9:  # still moving: no solution the data settles on
            raise Undetermined
    r, _, _ = model(alpha, x)
    rss = float(np.sum(r * r))
    try:
        inv = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        raise Undetermined from None
    cov = inv * (rss / dof)
    if ids is not None:
        rp = project(r, gn) if free_alpha else r
        scores = np.einsum("jip,ji->jp", jp, rp)
        lags = round(HAC_S / BLOCK_S)
        meat = newey_west(scores, ids, lags) * (3 * nb / dof)
        meat += hold * (rss / dof)  # the priors' share, as the data would have said it
        hac = inv @ meat @ inv
        # few blocks make the lagged sums unreliable: then never claim less than independent
        # blocks would give (with many, a tone's cancelling lags may rightly give less)
        cov = hac if nb >= 4 * lags else np.maximum(cov, hac)
        if normal_sigma is not None:  # d(residual)/dc = -sin(psi) (weighted, projected)
            th, _, cc = unpack(x)
            dc = np.sin(th[None, :] + (cc * a + lp)[:, None]) * (sw * normal_sigma)[:, None]
            q = np.einsum("jip,ji->jp", jp, dc)
            cov = cov + inv @ newey_west(q, ids, lags) @ inv
    if scale_sigma is not None:  # what a scale k = 1 +/- scale_sigma would move them by
        th, _, cc = unpack(x)
        psi = th[None, :] + (cc * a + lp)[:, None]
        _, d_psi, _ = model(alpha, x)
        jk = a[:, None] * np.cos(psi) + c[:, None] * np.sin(psi) + d_psi * (cc * a)[:, None]
        jk = jk * sw[:, None]
        if free_alpha:
            jk = project(jk, gn)
        shift = inv @ np.einsum("jip,ji->p", jp, jk)
        cov = cov + scale_sigma**2 * np.outer(shift, shift)
    if pitch_steps:  # what each measured change of the static pitch would move them by
        _, d_psi, _ = model(alpha, x)
        jl = d_psi * sw[:, None]
        if free_alpha:
            jl = project(jl, gn)
        per_block = np.einsum("jip,ji->jp", jp, jl)
        after = np.cumsum(per_block[::-1], axis=0)[::-1]  # sums over blocks j0 .. end
        for j0, sigma in pitch_steps:
            if j0 < nb:
                shift = inv @ after[j0]
                cov = cov + sigma**2 * np.outer(shift, shift)
    th, _, cc = unpack(x)
    b = np.zeros(3)
    b[off_idx] = x[3 : 3 + len(off_idx)]
    plain = r / sw[:, None]
    rms = math.sqrt(float(np.sum(plain**2)) / (3 * nb))
    tempco = x[d_col : d_col + 3].copy() if d_col is not None else np.zeros(3)
    return Solution(th.copy(), b, cov, rms, alpha, plain, cc, c_col, tempco, d_col)


def newey_west(scores: np.ndarray, ids: np.ndarray, lags: int) -> np.ndarray:
    """sum_j s_j s_j' plus the Bartlett-weighted cross products of scores up to ``lags``
    block indices apart (blocks missing in between count as zero scores)."""
    span = int(ids.max() - ids.min()) + 1
    full = np.zeros((span, scores.shape[1]))
    full[ids - ids.min()] = scores
    out = full.T @ full
    for lag in range(1, min(lags, span - 1) + 1):
        cross = full[:-lag].T @ full[lag:]
        out += (1.0 - lag / (lags + 1)) * (cross + cross.T)
    return out


def stops_of(rec: Recording, ids: np.ndarray) -> np.ndarray:
    """Per block of ``ids``: the number of the stop it is in (SPEED_REF reading exactly 0
    on every sample of the block, 0 for the recording's first stop if it starts standing,
    counted in order), -1 where the train moves."""
    block = np.floor(rec.time_s / BLOCK_S).astype(np.int64)
    standing = rec.speed == 0.0
    starts = standing & ~np.concatenate([[False], standing[:-1]])
    stop = np.cumsum(starts) - 1
    lo = int(block.min())
    span = int(block.max()) - lo + 1
    moving = np.bincount(block - lo, (~standing).astype(np.float64), minlength=span) > 0
    first = np.full(span, -1)
    np.maximum.at(first, block - lo, np.where(standing, stop, -1))
    out: np.ndarray = np.where(moving[ids - lo], -1, first[ids - lo])
    return out


def load_pitch(
    ids: np.ndarray, stops: np.ndarray, phi: np.ndarray
) -> tuple[np.ndarray, list[tuple[int, float]]]:
    """The body's static pitch per block (rad, 0 at the recording's start): the sum of its
    changes at the stops before the block. Passengers board while the train stands, and
    then the track under it does not change, so the change of the gravity's direction in
    the board (``phi`` per block) from soon after the stop (LOAD_SETTLE_S, the braking's
    transient gone; at once if the recording starts standing) to a little before the
    departure (LOAD_GUARD_S, before the odometer sees the train move) is the body's. Each
    window is LOAD_WINDOW_S long, but never more than LOAD_EDGE of the stop (its doors open
    and close inside); stops too short for both windows count as no change. Also returns
    each change as (first block after the stop, its 1 sigma from the windows' scatter)."""
    out = np.zeros(len(ids))
    steps: list[tuple[int, float]] = []
    total = 0.0
    done = 0  # blocks before this have their pitch
    for stop in np.unique(stops[stops >= 0]):
        where = np.flatnonzero(stops == stop)
        j0, j1 = int(where[0]), int(where[-1]) + 1
        out[done:j0] = total
        first, last = ids[j0] * BLOCK_S, (ids[j1 - 1] + 1) * BLOCK_S
        length = last - first
        t = (ids[where] + 0.5) * BLOCK_S - first
        settle = 0.0 if j0 == 0 else LOAD_SETTLE_S
        end0 = min(settle + LOAD_WINDOW_S, LOAD_EDGE * length)
        start1 = max(length - LOAD_GUARD_S - LOAD_WINDOW_S, (1.0 - LOAD_EDGE) * length)
        p0 = phi[where[(t >= settle) & (t < end0)]]
        p1 = phi[where[(t >= start1) & (t < length - LOAD_GUARD_S)]]
        out[j0:j1] = total
        done = j1
        if len(p0) > 1 and len(p1) > 1 and end0 <= start1:
            total += float(np.mean(p1) - np.mean(p0))
            var = float(np.var(p0, ddof=1)) + float(np.var(p1, ddof=1))  # n_eff ~ 1 each
            steps.append((j1, math.sqrt(var)))
    out[done:] = total
    return out, steps


def curvature(alpha: np.ndarray, x: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """d(alpha)/dx at each block: the slope of a straight line through the blocks' alphas
    along the track within CURVE_WINDOW_M of it, or the distance run in CURVE_WINDOW_S if
    longer (the alphas carry the odometer's noise, correlated over about a second), kept
    only where it stands out of that line's scatter (CURVE_SIGNIFICANCE sigma): 0 on a
    straight grade, while standing, or where the blocks span less than a quarter of the
    window."""
    order = np.argsort(x, kind="stable")
    xs, al = x[order], alpha[order]
    half = np.maximum(CURVE_WINDOW_M, np.abs(speed[order]) * CURVE_WINDOW_S)
    lo = np.searchsorted(xs, xs - half, side="left")
    hi = np.searchsorted(xs, xs + half, side="right")
    x0 = xs - xs[0]
    a0 = al - np.median(al)
    n, sx, sa, sxx, sxa, saa = window_sums(
        (np.ones(len(xs)), x0, a0, x0 * x0, x0 * a0, a0 * a0), lo, hi
    )
    sxx_c = sxx - sx * sx / n
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = (sxa - sx * sa / n) / sxx_c
        ssr = np.maximum(saa - sa * sa / n - slope * slope * sxx_c, 0.0)
        sigma = np.sqrt(ssr / np.maximum(n - 2.0, 1.0) / sxx_c)
        wide = sxx_c / n > (half / 4.0) ** 2 / 3.0  # spread of a line of blocks >= W/4 long
        keep = wide & np.isfinite(slope) & (np.abs(slope) > CURVE_SIGNIFICANCE * sigma)
    out = np.zeros(len(x))
    out[order] = np.where(keep, slope, 0.0)
    return out


def curve_sigma(c: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """1 sigma of the modelled c per block: CURVE_MODEL_SHARE of the largest |c| within
    CURVE_WINDOW_S of it (the line through the alphas blurs a curve's ends, where c
    steps)."""
    if not len(ids):
        return np.zeros(0)
    span = int(ids.max() - ids.min()) + 1
    full = np.zeros(span)
    full[ids - ids.min()] = np.abs(c)
    reach = round(CURVE_WINDOW_S / BLOCK_S)
    padded = np.concatenate([np.zeros(reach), full, np.zeros(reach)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * reach + 1)
    return CURVE_MODEL_SHARE * windows.max(axis=1)[ids - ids.min()]


def scatter_weights(resid: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """1 / the local power of the fit's residuals (a running mean over SCATTER_S of each
    block's residual sum of squares, relative to the quietest blocks'): the car body's
    vibration grows with speed, so a block at 3 m/s says far more than one at 30 m/s."""
    power = np.sum(resid * resid, axis=1)
    span = int(ids.max() - ids.min()) + 1
    full = np.zeros(span)
    have = np.zeros(span)
    full[ids - ids.min()] = power
    have[ids - ids.min()] = 1.0
    half = round(SCATTER_S / BLOCK_S)
    kernel = np.ones(2 * half + 1)
    local = np.convolve(full, kernel, "same") / np.maximum(np.convolve(have, kernel, "same"), 1.0)
    local = local[ids - ids.min()]
    floor = max(float(np.percentile(local, 10)), 1e-12)
    return floor / np.maximum(local, floor)


def taper(ids: np.ndarray) -> np.ndarray:
    """Weights of the blocks: rising as a raised cosine over TAPER_S from each edge of a
    run of consecutive blocks, 1 inside."""
    if not len(ids):
        return np.ones(0)
    new_run = np.concatenate([[True], np.diff(ids) > 1])
    run = np.cumsum(new_run) - 1
    start = ids[new_run][run]
    end = ids[np.concatenate([new_run[1:], [True]])][run]
    edge = (np.minimum(ids - start, end - ids) + 0.5) * BLOCK_S
    return 0.5 * (1.0 - np.cos(np.pi * np.clip(edge / TAPER_S, 0.0, 1.0)))


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
    standstill = rec.speed == 0.0 if rec.has_speed_ref else np.ones(n, dtype=bool)
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
    blocks = block_means(rec, keep)
    ids, m, a = blocks.ids, blocks.acc, blocks.a
    if len(ids) < 2:
        raise BenchError(f"calibration: too little usable data against the {name}")
    moving = reference == "speed"
    hint = "; it needs more acceleration and braking" if moving else ""
    if moving:
        accel_s = float(np.sum(taper(ids) * (np.abs(a) >= MIN_ACCEL_MPS2))) * BLOCK_S
        if accel_s < MIN_ACCEL_S:
            raise BenchError(
                f"calibration: the recording does not determine the angles ({accel_s:.1f} s "
                f"of steady acceleration or braking, {MIN_ACCEL_S:g} s needed){hint}"
            )
    g = config.g
    theta0 = np.asarray(config.angles_rad, dtype=np.float64)
    if reference == "speed":  # start each block's gradient where the starting angles put it
        u, w = solve(m, np.full(len(m), FULL), geometry(theta0))
        alpha = np.arctan2(u - a, w)
        pitch, pitch_steps = load_pitch(ids, stops_of(rec, ids), np.arctan2(u, w))
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
    weights = taper(ids) if moving else None
    temperature = None  # K from the first block's, where the board's warmed or cooled
    if moving and np.isfinite(blocks.temp).all() and np.ptp(blocks.temp) >= TEMPCO_MIN_K:
        temperature = blocks.temp - blocks.temp[0]

    def fit(fit_offset: np.ndarray) -> Solution:
        """The fit; in motion iterated with c = v^2 d(alpha)/dx from its own alphas, and
        with the odometer's scale and the body's compliance fitted."""
        c = np.zeros(len(ids))
        w = weights
        for it in range(CURVE_ITER if moving else 1):
            sol = _solve(
                m,
                a,
                alpha,
                moving,
                g,
                theta0,
                fit_offset,
                c,
                w,
                ids,
                curve_sigma(c, ids),
                WHEEL_ERROR_SIGMA if moving else None,
                (COMPLIANCE_RAD, COMPLIANCE_SIGMA_RAD) if moving else None,
                pitch if moving else None,
                pitch_steps if moving else None,
                temperature,
            )
            if not moving:
                break
            c_new = blocks.v2 * curvature(sol.alpha, blocks.x, np.sqrt(blocks.v2))
            w_new = weights * scatter_weights(sol.resid, ids)
            if (np.max(np.abs(c_new - c)) < 1e-5 and it > 0) or it == CURVE_ITER - 1:
                break
            c, w = c_new, w_new
        return sol

    while True:
        try:
            sol = fit(fit_offset)
        except Undetermined:
            if fit_offset.any():  # offsets first: they are the usual reason
                fit_offset[:] = False
                continue
            raise BenchError(
                f"calibration: the recording does not determine the angles{hint}"
            ) from None
        sig = np.sqrt(np.clip(np.diag(sol.cov), 0.0, None))
        off_sig = np.full(3, np.nan)
        off_sig[fit_offset] = sig[3 : 3 + int(fit_offset.sum())]
        weak = fit_offset & ~(off_sig <= OFFSET_SIGMA_MAX)
        if not weak.any():
            break
        fit_offset &= ~weak  # not determined by the data: keep the config's, fit again
    theta, b, rms = sol.theta, sol.b, sol.rms
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
    # three channels: tuple() cannot say how many
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
        compliance_deg_per_mps2=math.degrees(sol.compliance),
        compliance_sigma=(
            math.degrees(float(sig[sol.c_col])) if sol.c_col is not None else math.nan
        ),
    )
