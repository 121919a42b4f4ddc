"""The calibration config (TOML): board id, as-built channel angles and scales, fusion settings.

Every key is optional; defaults are the ICD's nominal values. Validation is strict and
each failure is one line naming the file and key, because a silently ignored typo in an
angle would make every result on the bench wrong. A Config also says where it came from
(:attr:`Config.origin`, :meth:`Config.describe`): a result is only as good as the angles
behind it, so every command prints that and every log and record stores it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from bench.errors import ConfigError
from devices.textfile import parse_toml, read_text_file
from devices.tomlcheck import error, is_integer, is_number, number_problem, to_float
from protocol.layout import (
    DEFAULT_BASE,
    DEFAULT_SAMPLE_RATE_HZ,
    G0,
    NOMINAL_ANGLES_DEG,
    NOMINAL_SCALE,
)


@dataclass(frozen=True, slots=True)
class ChannelCal:
    angle_deg: float
    scale: float = NOMINAL_SCALE  # m/s^2 per LSB
    offset: float = 0.0  # LSB


@dataclass(frozen=True, slots=True)
class EstimatorSettings:
    """Settings of the bench's own estimator (METHOD.md section 5, docs/ESTIMATOR.md)."""

    residual_limit_mps2: float = 0.02  # moving-mean residual beyond this singles a channel out
    residual_window_s: float = 0.1  # the residual's moving mean spans this long
    stuck_window_s: float = 0.5  # no code change for this long while others change
    recover_s: float = 1.0  # healthy for this long before an excluded channel is readmitted
    standstill_s: float = 1.0  # SPEED_REF at 0 for this long -> a_ref exactly 0
    coast_s: float = 0.5  # a_ref held this long after SPEED_REF stops, then unavailable
    speed_noise_mps: float = 0.003  # Kalman measurement noise (odometer speed), m/s
    jerk_psd: float = 1e-4  # Kalman process noise (white jerk), (m/s^3)^2/Hz
    a_ref_sigma_mps2: float = 0.01  # a_ref unavailable while the filter's own 1-sigma exceeds this
    clock_drift_ppm: float = 1000.0  # how fast a clock offset estimate may rise (ppm of time)
    # the joint filter (docs/ESTIMATOR.md): process noise
    accel_psd: float = 0.1  # acceleration random walk, (m/s^2)^2/s
    grade_psd_per_m: float = 1e-9  # g sin(alpha) random walk per metre, (m/s^2)^2/m
    grade_rate_psd_per_m: float = 1e-8  # its rate per metre, ((m/s^2)/m)^2/m (smooth ride)
    grade_rate_psd_rough_per_m: float = 1e-9  # the same on a rough ride (w cannot pin k)
    rough_ride_mps2: float = 0.02  # spread of w's 0.05 s block means at which a ride is rough
    blind_grade_rate_psd_per_m: float = 1e-7  # the same while no odometer frame is accepted
    grade_sigma0_mps2: float = 0.5  # 1-sigma of g sin(alpha) before any information
    grade_rate_sigma0: float = 0.001  # 1-sigma of its rate per metre at the start, (m/s^2)/m
    grade_rate_jump: float = 0.003  # 1-sigma added to k when the odometer shows a missed curve
    # odometer
    speed_quantum_mps: float = 0.001  # SPEED_REF resolution (adds quantum^2/12 of variance)
    odometer_noise_floor_mps: float = 0.0005  # least odometer noise the filter assumes
    speed_noise_max_mps: float = 0.05  # cap of the noise learnt from the odometer innovations
    odometer_latency_s: float = 0.0  # SPEED_REF reports v(t - latency) beyond the clock mapping
    latency_sigma_s: float = 0.03  # initial 1-sigma of that latency; 0 = not estimated
    latency_psd: float = 1e-6  # its random walk, s^2/s (when estimated)
    latency_min_accel_mps2: float = 0.35  # estimated only while |a| exceeds this (observable)
    odometer_gate_sigma: float = 4.0  # innovation beyond this many sigma: frame rejected
    suspect_recover_s: float = 0.5  # accepted frames for this long before "suspect" clears
    odometer_reset_s: float = 2.0  # rejected this long: restart the speed at the odometer
    slip_accel_mps2: float = 0.3  # innovation slope beyond this: slip/slide, not the model
    # standstill and channels
    zupt_accel_sigma_mps2: float = 0.002  # zero-velocity update: a = 0 with this 1-sigma
    zupt_gate_mps2: float = 0.02  # |u - g sin(alpha)| beyond this at standstill: it moves
    channel_noise_floor_mps2: float = 1e-5  # least channel noise assumed (1-sigma)
    channel_noise_tau_s: float = 2.0  # time constant of the noise learnt from the residual
    # the normal specific force w: vertical curves (v^2/R) tell the grade's rate
    w_block_s: float = 0.05  # w averaged over blocks this long (0: w not used)
    w_bias_psd: float = 1e-9  # w bias random walk, (m/s^2)^2/s
    w_bias_sigma0_mps2: float = 0.01  # 1-sigma of the w bias at the start
    vertical_radius_min_m: float = 500.0  # the sharpest vertical curve the line has
    curve_detect_s: float = 0.3  # time constant of the vertical-curve detector on w
    curve_detect_sigma: float = 4.0  # it fires beyond this many of its learnt sigmas
    curve_detect_min_mps2: float = 0.02  # and beyond this change of w (v^2/R)
    vibration_corr_s: float = 0.1  # correlation time of what the notch leaves of the vibration
    vibration_notch_radius: float = 0.9  # adaptive notch on w for the body's bounce (0: none)
    drift_llr: float = 10.0  # log-likelihood lead that names a drifting channel early (0: off)
    bias_sigma_mps2: float = 0.0005  # sensors' bias left after calibration (drift), in sigma
    body_velocity_tau_s: float = 0.05  # correlation time given the body's vertical speed (0: off)
    body_velocity_mismatch: float = 0.1  # share of the w blocks' vibration left in their R
    curve_visible_speed_mps: float = 25.0  # below, k walks faster on a rough ride (0: never)
    curve_rewind_s: float = 1.0  # a curve found up to this long after it began is replayed (0: off)


ZERO_ALLOWED = frozenset(
    {
        "odometer_latency_s",
        "latency_sigma_s",
        "w_block_s",
        "bias_sigma_mps2",
        "vibration_notch_radius",
        "drift_llr",
        "body_velocity_tau_s",
        "curve_rewind_s",
        "curve_visible_speed_mps",
    }
)
"""Estimator settings that may be 0 (every other one must be > 0)."""
SIGMA_LIMIT_MAX = 100.0
"""Upper bound of fusion.gradient_sigma_limit_permil (beyond it a sigma says nothing)."""


@dataclass(frozen=True, slots=True)
class Config:
    base_id: int = DEFAULT_BASE
    sample_rate_hz: int = DEFAULT_SAMPLE_RATE_HZ  # until the board's status frame says otherwise
    # three channels: tuple() cannot say how many
    channels: tuple[ChannelCal, ChannelCal, ChannelCal] = tuple(  # type: ignore[assignment]
        ChannelCal(a) for a in NOMINAL_ANGLES_DEG
    )
    g: float = G0
    tolerance_permil: float = 1.0
    gradient_sigma_limit_permil: float = 0.35  # estimator gradient withheld beyond this 1-sigma
    estimator: EstimatorSettings = field(default_factory=EstimatorSettings)
    source: str = "<defaults>"
    path: str | None = None  # the file it was read from
    # where the values came from (ORIGINS); provenance, not part of the calibration's value
    origin: str = field(default="nominal", compare=False)
    recorded_in: str | None = field(default=None, compare=False)  # the log it was read back from

    def describe(self) -> str:
        """Where this calibration came from, for people: one short phrase."""
        if self.origin == "file":
            where = f"file {self.path or self.source}"
        elif self.origin in ("scenario", "plan"):
            where = self.source
        else:
            where = "nominal ICD values"
        if self.recorded_in is not None:
            where = f"recorded in {self.recorded_in} ({where})"
        return where

    def angles_text(self) -> str:
        """The three angles and the vote tolerance, the figures an operator checks first."""
        angles = ", ".join(f"ch{k} {c.angle_deg:g} deg" for k, c in enumerate(self.channels, 1))
        return f"{angles}; tolerance {self.tolerance_permil:g} permil"

    def announcement(self) -> str:
        """The line every command prints: which calibration, from where, its angles."""
        return f"calibration: {self.describe()} ({self.angles_text()})"

    @property
    def angles_rad(self) -> tuple[float, float, float]:
        a1, a2, a3 = (math.radians(c.angle_deg) for c in self.channels)
        return a1, a2, a3

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["channels"] = [asdict(c) for c in self.channels]
        return d

    def to_toml(self) -> str:
        """The config as TOML that :func:`load_config` reads back to an equal Config."""
        lines = [
            "[board]",
            f"base_id = 0x{self.base_id:X}",
            f"sample_rate_hz = {self.sample_rate_hz}",
            "",
        ]
        for c in self.channels:
            lines += [
                "[[channels]]",
                f"angle_deg = {c.angle_deg!r}",
                f"scale = {c.scale!r}",
                f"offset = {c.offset!r}",
                "",
            ]
        lines += [
            "[fusion]",
            f"g = {self.g!r}",
            f"tolerance_permil = {self.tolerance_permil!r}",
            f"gradient_sigma_limit_permil = {self.gradient_sigma_limit_permil!r}",
            "",
        ]
        lines.append("[estimator]")
        lines += [f"{k} = {v!r}" for k, v in asdict(self.estimator).items()]
        return "\n".join(lines) + "\n"


def _number(
    source: str,
    path: str,
    value: Any,
    lo: float | None = None,
    *,
    lo_open: bool = False,
    integer: bool = False,
    hi: float | None = None,
    why: str = "",
) -> float:
    """A number within [lo, hi] (lo exclusive with lo_open); ``why`` says where the bound
    comes from in the error message."""
    if not (is_integer(value) if integer else is_number(value)):
        kind = "an integer" if integer else "a number"
        raise error(source, path, f"expected {kind}, got {value!r}")
    problem = number_problem(to_float(value), lo, hi, lo_open=lo_open)
    if problem:
        raise error(source, path, problem + (f" ({why})" if why else ""))
    return value


ESTIMATOR_MAX: dict[str, float] = {
    "residual_limit_mps2": 100.0,
    "residual_window_s": 10.0,
    "stuck_window_s": 60.0,
    "recover_s": 3600.0,
    "standstill_s": 3600.0,
    "coast_s": 60.0,
    "speed_noise_mps": 100.0,
    "jerk_psd": 1e6,
    "a_ref_sigma_mps2": 100.0,
    "clock_drift_ppm": 1e6,
    "accel_psd": 1e3,
    "grade_psd_per_m": 1.0,
    "grade_rate_psd_per_m": 1.0,
    "grade_rate_psd_rough_per_m": 1.0,
    "rough_ride_mps2": 10.0,
    "blind_grade_rate_psd_per_m": 1.0,
    "grade_sigma0_mps2": 10.0,
    "grade_rate_sigma0": 1.0,
    "grade_rate_jump": 1.0,
    "speed_quantum_mps": 10.0,
    "odometer_noise_floor_mps": 100.0,
    "speed_noise_max_mps": 100.0,
    "odometer_latency_s": 10.0,
    "latency_sigma_s": 10.0,
    "latency_psd": 1.0,
    "latency_min_accel_mps2": 100.0,
    "odometer_gate_sigma": 1000.0,
    "suspect_recover_s": 3600.0,
    "odometer_reset_s": 3600.0,
    "slip_accel_mps2": 100.0,
    "zupt_accel_sigma_mps2": 100.0,
    "zupt_gate_mps2": 100.0,
    "channel_noise_floor_mps2": 100.0,
    "channel_noise_tau_s": 3600.0,
    "w_block_s": 10.0,
    "w_bias_psd": 1.0,
    "w_bias_sigma0_mps2": 10.0,
    "vertical_radius_min_m": 1e6,
    "curve_detect_s": 10.0,
    "curve_detect_sigma": 100.0,
    "curve_detect_min_mps2": 100.0,
    "vibration_corr_s": 10.0,
    "vibration_notch_radius": 0.999,
    "drift_llr": 1e6,
    "bias_sigma_mps2": 1.0,
    "body_velocity_tau_s": 10.0,
    "body_velocity_mismatch": 1.0,
    "curve_rewind_s": 1.5,
    "curve_visible_speed_mps": 200.0,
}
"""Largest sensible value of each estimator setting: windows are held in memory as
samples (10 s at 1 kHz is 10 000), and beyond these the estimator means nothing."""


def _table(where: str, value: Any, allowed: set[str]) -> dict[str, Any]:
    # not tomlcheck.Table: the config's messages name Python types and the first unknown key
    # in sorted order, and they stay as operators know them
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: expected a table, got {type(value).__name__}")
    unknown = sorted(set(value) - allowed)
    if unknown:
        raise ConfigError(
            f"{where}.{unknown[0]}: unknown key (expected one of {', '.join(sorted(allowed))})"
        )
    return value


MIN_SAMPLE_RATE_HZ, MAX_SAMPLE_RATE_HZ = 50, 1000
"""The ADC sample rates the ICD allows (section 1)."""
MAX_SCALE = 1e-3
"""Largest channel scale, m/s^2 per LSB (full scale 2^23 LSB would be 8 400 m/s^2)."""
CODE_LIMIT = float(1 << 23)
"""Largest offset magnitude, LSB: a 24-bit two's complement code."""
MIN_ANGLE_APART_DEG = 5.0
"""Closest two channel angles may be: the ICD mounts them 30 deg apart; at 5 deg a pair's
gradient already amplifies sensor noise 11-fold, near 0 it is singular."""

ORIGINS = ("nominal", "file", "scenario", "plan")
"""Where a calibration comes from: the ICD's nominal values, a calibration file, an emulated
board as built (its scenario), or an acceptance plan's scenario with the plan's overlay."""

_SCENARIO_KEYS = frozenset(
    {"description", "seed", "duration_s", "track", "train", "faults", "odometer", "speed_ref"}
)


def _refuse_other_files(source: str, data: dict[str, Any]) -> None:
    """A scenario or a plan given where a calibration belongs: say what it is, in one line."""
    scenario_keys = sorted(_SCENARIO_KEYS & set(data))
    if scenario_keys:
        raise ConfigError(
            f"{source}: this is an emulator scenario (it has {scenario_keys[0]!r}), not a "
            "calibration config: emulated runs use the scenario's board as built without "
            f"--config; to write that calibration: bench emulate {source} --calibration-out "
            "cal.toml"
        )
    if "plan" in data:
        raise ConfigError(
            f"{source}: this is an acceptance plan (it has [plan]), not a calibration config: "
            "run it with bench accept"
        )


def config_from_dict(
    data: dict[str, Any],
    source: str = "<dict>",
    path: str | None = None,
    *,
    origin: str = "file",
) -> Config:
    """Validate a parsed TOML document into a Config. Raises ConfigError naming the key."""
    if origin not in ORIGINS:
        raise ValueError(f"origin must be one of {ORIGINS}, got {origin!r}")
    if isinstance(data, dict):
        _refuse_other_files(source, data)
    _table(source, data, {"board", "channels", "fusion", "estimator"})
    board = _table(f"{source}: board", data.get("board", {}), {"base_id", "sample_rate_hz"})
    base_id = int(
        _number(source, "board.base_id", board.get("base_id", DEFAULT_BASE), integer=True)
    )
    if not 0 <= base_id <= 0x7FC or base_id <= 0x180 < base_id + 4:
        raise error(
            source,
            "board.base_id",
            f"0x{base_id:X} is not a usable 11-bit base (must be 0..0x7FC with "
            "BASE..BASE+3 clear of SPEED_REF 0x180)",
        )
    rate = int(
        _number(
            source,
            "board.sample_rate_hz",
            board.get("sample_rate_hz", DEFAULT_SAMPLE_RATE_HZ),
            MIN_SAMPLE_RATE_HZ,
            integer=True,
            hi=MAX_SAMPLE_RATE_HZ,
            why=f"the ICD's ADC rates are {MIN_SAMPLE_RATE_HZ}..{MAX_SAMPLE_RATE_HZ} Hz",
        )
    )
    chans = data.get("channels", [])
    if not isinstance(chans, list) or len(chans) not in (0, 3):
        raise error(source, "channels", "expected exactly three [[channels]] tables (ch1..ch3)")
    cals = []
    for i, default_angle in enumerate(NOMINAL_ANGLES_DEG):
        where = f"channels[{i + 1}]"
        ch = _table(
            f"{source}: {where}", chans[i] if chans else {}, {"angle_deg", "scale", "offset"}
        )
        angle = _number(source, f"{where}.angle_deg", ch.get("angle_deg", default_angle))
        if not -90.0 < angle < 90.0:
            raise error(source, f"{where}.angle_deg", f"must lie in (-90, 90) deg, got {angle!r}")
        scale = _number(
            source,
            f"{where}.scale",
            ch.get("scale", NOMINAL_SCALE),
            0,
            lo_open=True,
            hi=MAX_SCALE,
            why="m/s^2 per LSB; nominal 2.34e-6",
        )
        offset = _number(
            source,
            f"{where}.offset",
            ch.get("offset", 0.0),
            -CODE_LIMIT,
            hi=CODE_LIMIT,
            why="LSB of a 24-bit code",
        )
        cals.append(ChannelCal(float(angle), float(scale), float(offset)))
    angles = [c.angle_deg for c in cals]
    for i, j in ((0, 1), (1, 2), (0, 2)):
        apart = abs(angles[i] - angles[j])
        if not apart >= MIN_ANGLE_APART_DEG:
            raise error(
                source,
                "channels",
                f"ch{i + 1} and ch{j + 1} angle_deg must be at least {MIN_ANGLE_APART_DEG:g} deg "
                f"apart (each pair's gradient divides by sin(theta_i - theta_j)), got "
                f"{angles[i]!r} and {angles[j]!r}",
            )
    fusion = _table(
        f"{source}: fusion",
        data.get("fusion", {}),
        {"g", "tolerance_permil", "gradient_sigma_limit_permil"},
    )
    g = _number(
        source, "fusion.g", fusion.get("g", G0), 1.0, hi=20.0, why="m/s^2; 9.80665 on Earth"
    )
    tol = _number(
        source,
        "fusion.tolerance_permil",
        fusion.get("tolerance_permil", 1.0),
        0,
        hi=1000.0,
        why="permil",
    )
    limit = _number(
        source,
        "fusion.gradient_sigma_limit_permil",
        fusion.get("gradient_sigma_limit_permil", 0.35),
        0,
        lo_open=True,
        hi=SIGMA_LIMIT_MAX,
        why="permil",
    )
    est_defaults = asdict(EstimatorSettings())
    est = _table(f"{source}: estimator", data.get("estimator", {}), set(est_defaults))
    est_values = {
        k: float(
            _number(
                source,
                f"estimator.{k}",
                est.get(k, v),
                0,
                lo_open=k not in ZERO_ALLOWED,
                hi=ESTIMATOR_MAX[k],
            )
        )
        for k, v in est_defaults.items()
    }
    return Config(
        base_id=base_id,
        sample_rate_hz=rate,
        channels=tuple(cals),  # type: ignore[arg-type]  # three: checked above
        g=float(g),
        tolerance_permil=float(tol),
        gradient_sigma_limit_permil=float(limit),
        estimator=EstimatorSettings(**est_values),
        source=source,
        path=path,
        origin=origin,
    )


def load_config(path: str | Path | None) -> Config:
    """Read a config file; None gives the nominal defaults."""
    if path is None:
        return Config()
    p = Path(path)
    data = parse_toml(read_text_file(p, "config"), str(p))
    return config_from_dict(data, source=p.name, path=str(p))
