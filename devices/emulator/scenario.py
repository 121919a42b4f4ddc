"""Scenario files (TOML) for the virtual board: parse, validate, default.

A scenario describes one simulated run: the world (track, train, gravity), the board as
built (angles, biases, noise, timing) and the faults to inject. Validation is strict and
every failure is one :class:`ConfigError` line naming the file and the key, because a
silently ignored typo would make a test run prove nothing.

Indices in messages count from 1 in file order (``channels[1]`` is ch1), as in the
calibration config. The annotated reference of every key is ``devices/scenarios/example.toml``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from devices.errors import ConfigError
from devices.textfile import parse_toml, path_or_packaged, read_text_file
from devices.tomlcheck import Table, is_integer, printable
from protocol.layout import (
    DEFAULT_BASE,
    DEFAULT_SAMPLE_RATE_HZ,
    G0,
    NOMINAL_ANGLES_DEG,
    NOMINAL_SCALE,
    SPEED_REF_ID,
    STATUS_BIT_NAMES,
)

SCENARIO_DIR = Path(__file__).resolve().parent.parent / "scenarios"
"""Built-in scenarios shipped with the package (``devices/scenarios/*.toml``)."""

MAX_DURATION_S = 3600.0
CAN_TARGETS = ("adc", "status", "speed", "bus")
"""Named fault targets besides the channel numbers 1..3 (and "uart" for UART faults)."""

# kind -> (allowed targets, {param: default}); None default = optional without default.
SIGNAL_KINDS = ("stuck", "drift", "spike", "saturate", "status")
FRAME_KINDS = ("dropout", "crc", "loss", "duplicate", "reorder", "counter_jump")
UART_KINDS = ("noise", "truncation")
FAULT_KINDS = SIGNAL_KINDS + FRAME_KINDS + UART_KINDS
FAULT_PARAMS: dict[str, dict[str, Any]] = {
    "dropout": {},
    "stuck": {"code": None},
    "drift": {"rate_mps2_per_s": 0.01, "offset_mps2": 0.0},
    "spike": {"amplitude_mps2": 5.0, "rate_hz": 1.0, "width_samples": 1},
    "saturate": {"value_mps2": 25.0},
    "status": {"bits": 0x02},
    "crc": {"probability": 1.0},
    "loss": {"probability": 0.1},
    "duplicate": {"probability": 0.1},
    "reorder": {"probability": 0.1, "depth": 1},
    "counter_jump": {"jump": 17},
    "noise": {"probability": 0.01, "burst_bytes": 4},
    "truncation": {"probability": 0.01},
}
_COMMON_FAULT_KEYS = ("channel", "kind", "start_s", "end_s")


@dataclass(frozen=True, slots=True)
class TrackSegment:
    length_m: float
    gradient_permil: float
    vertical_curve_m: float | None = None  # transition INTO this segment; None = scenario default


@dataclass(frozen=True, slots=True)
class TrainPhase:
    duration_s: float
    accel_mps2: float
    allow_reverse: bool = False  # may this phase take the speed through zero?
    jerk_mps3: float | None = None  # ramp limit into this phase; None = the scenario's jerk_mps3


@dataclass(frozen=True, slots=True)
class ChannelModel:
    """One as-built sensor: what it really is, not what the calibration sheet says."""

    angle_deg: float
    bias_mps2: float = 0.0
    scale_error: float = 0.0  # relative: measured = true * (1 + scale_error)
    noise_mps2: float = 0.0  # white noise standard deviation
    vibration_mps2: float = 0.0  # sine amplitude along the sensitive axis
    vibration_hz: float = 0.0
    vibration_phase_deg: float = 0.0
    bias_tempco_mps2_per_k: float = 0.0  # bias change per kelvin away from the start temperature
    bias_walk_mps2_per_sqrt_s: float = (
        0.0  # bias random walk: its sigma after T s is this * sqrt(T)
    )
    thermal_lag_s: float = 0.0  # the channel's own temperature lags the board's by this


@dataclass(frozen=True, slots=True)
class BoardModel:
    temperature_c: int = 35  # at the start of the run (the calibration's temperature)
    temperature_end_c: float | None = None  # approached exponentially; None = stays constant
    temperature_tau_s: float = 900.0  # time constant of the approach
    station_cooling_k: float = 0.0  # the target is this much lower while standing at a station
    supply_v: float = 24.0
    errors0: int = 0
    status_counter0: int = 0
    latency_us: int = 100  # sampling instant -> frames queued for the bus
    frame_gap_us: int = 250  # bus time of one frame (8 bytes at 500 kbit/s)
    status_offset_us: int = 500  # BOARD_STATUS queued at k * 100 ms + this
    antialias_filter: bool = True  # the ADC's sinc^3 decimator (devices/emulator/antialias.py)


@dataclass(frozen=True, slots=True)
class OdometerModel:
    """The train's odometer unit: its own clock, schedule and speed error."""

    time0_ticks: int = 0
    drift_ppm: float = 0.0
    offset_s: float = 0.0037  # first SPEED_REF after this much true time
    noise_mps: float = 0.0
    lag_s: float = 0.0  # latency: the speed it reports is this old
    counter0: int = 0
    resolution_mps: float = 0.0  # speed quantisation step (0: the wire's 1 mm/s)
    slide_depth_mps: float = 0.0  # wheel slide while braking: deepest shortfall of one cycle
    slide_period_s: float = 1.2  # one WSP cycle: slide develops, brake released, wheel recovers
    slide_min_decel_mps2: float = 0.3  # slides only while braking harder than this
    slip_depth_mps: float = 0.0  # wheel slip while motoring: largest excess of one cycle
    slip_period_s: float = 1.0
    slip_min_accel_mps2: float = 0.3  # slips only while accelerating harder than this
    wsp_jitter: float = 0.0  # each cycle's depth is depth * (1 - wsp_jitter * U(0, 1))
    low_adhesion_start_s: float = 0.0  # slide and slip happen only inside this time window
    low_adhesion_end_s: float | None = None  # None = the end of the run
    wheel_diameter_error: float = 0.0  # e: reported speed = wheel speed * (1 + e)


@dataclass(frozen=True, slots=True)
class VibrationModel:
    """The car body's rigid-body vibration (one motion, felt by all three sensors alike).

    Amplitudes hold at ``reference_speed_mps`` and scale with (|v| / reference)^exponent;
    none at standstill."""

    vertical_mps2: float = 0.0  # tonal amplitude of the body's bounce mode
    longitudinal_mps2: float = 0.0  # tonal amplitude along the track
    frequency_hz: float = 2.5
    longitudinal_phase_deg: float = 90.0  # longitudinal tone relative to the vertical one
    broadband_vertical_mps2: float = 0.0  # RMS of the broadband part
    broadband_longitudinal_mps2: float = 0.0
    broadband_low_hz: float = 0.5
    broadband_high_hz: float = 20.0
    reference_speed_mps: float = 20.0
    speed_exponent: float = 1.0

    @property
    def active(self) -> bool:
        return bool(
            self.vertical_mps2
            or self.longitudinal_mps2
            or self.broadband_vertical_mps2
            or self.broadband_longitudinal_mps2
        )


@dataclass(frozen=True, slots=True)
class BodyPitchModel:
    """The car body's pitch on its secondary suspension (devices.emulator.body_pitch): a
    second-order response to the train's acceleration, plus a static load pitch that
    changes at stations. Defaults: a metro car (docs/EMULATOR.md derives them)."""

    enabled: bool = True
    compliance_deg_per_mps2: float = 0.05  # settled pitch per m/s^2, nose up accelerating
    frequency_hz: float = 1.2  # the body's pitch mode
    damping_ratio: float = 0.25
    static_deg: float = 0.0  # the load's pitch at the start (0: as calibrated)
    load_step_deg: float = 0.02  # standard deviation of its change at each station
    min_dwell_s: float = 10.0  # a stop at least this long is a station


@dataclass(frozen=True, slots=True)
class StandstillModel:
    """What a standing car still feels (devices.emulator.standstill): the HVAC's hum, the
    doors' jolts and the passengers' boarding sway at stations."""

    enabled: bool = True
    hvac_mps2: float = 0.01  # tone amplitude normal to the track (half of it along)
    hvac_hz: float = 14.0
    door_mps2: float = 0.1  # peak jolt along the track as a door opens or closes
    door_hz: float = 8.0  # the body rings at this frequency...
    door_decay_s: float = 0.3  # ...decaying with this time constant
    boarding_rate_hz: float = 0.5  # passengers per second while the doors are open
    boarding_step_deg: float = 0.002  # standard deviation of one passenger's pitch step


@dataclass(frozen=True, slots=True)
class ModeModel:
    """One car-body mode: RMS at the reference speed (m/s^2, or deg for pitch), natural
    frequency and damping ratio (devices/emulator/body_modes.py)."""

    rms: float
    frequency_hz: float
    damping: float


MODE_DEFAULTS: dict[str, ModeModel] = {
    "bounce": ModeModel(0.06, 1.2, 0.2),  # m/s^2 RMS: the body on its secondary suspension
    "pitch": ModeModel(0.01, 1.5, 0.2),  # deg RMS: the body rocking about its centre
    "bending": ModeModel(0.04, 9.0, 0.03),  # m/s^2 RMS: the shell's first vertical bending
}
MODE_UNITS = {"bounce": "rms_mps2", "pitch": "rms_deg", "bending": "rms_mps2"}


@dataclass(frozen=True, slots=True)
class BodyModesModel:
    """The car body's bounce, pitch and bending modes at once, driven by the track; on by
    default (a real car always has them). Amplitudes hold at ``reference_speed_mps`` and
    scale with (|v| / reference)^exponent; none at standstill."""

    enabled: bool = True
    bounce: ModeModel = MODE_DEFAULTS["bounce"]
    pitch: ModeModel = MODE_DEFAULTS["pitch"]
    bending: ModeModel = MODE_DEFAULTS["bending"]
    lever_m: float = 0.0  # the board's distance ahead of the pitch centre
    reference_speed_mps: float = 20.0
    speed_exponent: float = 1.0

    @property
    def active(self) -> bool:
        return self.enabled and bool(self.bounce.rms or self.pitch.rms or self.bending.rms)


@dataclass(frozen=True, slots=True)
class TrackFeature:
    """One point of the line the car feels (a switch, an insulated joint, a weld dip)."""

    position_m: float
    amplitude_mps2: float  # the ring's amplitude at the reference speed (< 0: drops first)
    frequency_hz: float
    damping: float


@dataclass(frozen=True, slots=True)
class IrregularityModel:
    """Track irregularity fixed in position (devices.emulator.irregularity): listed
    features and periodic rail joints, each felt by every axle as a damped ring whose
    amplitude scales with (|v| / reference)^exponent. None by default: where a line's
    switches and joints lie is the line's own."""

    enabled: bool = True
    features: tuple[TrackFeature, ...] = ()
    joint_spacing_m: float = 0.0  # periodic joints (jointed rail); 0: continuously welded
    joint_start_m: float = 0.0
    joint_amplitude_mps2: float = 0.3
    joint_spread: float = 0.5  # each joint's amplitude uniform in amplitude (1 +- spread)
    frequency_hz: float = 9.0  # the ring of the periodic joints and the features' default
    damping: float = 0.1
    axles_m: tuple[float, ...] = (0.0,)  # each axle's distance ahead of the board
    reference_speed_mps: float = 20.0
    speed_exponent: float = 1.0
    track_seed: int = 0  # the line's joints: independent of the run's seed

    @property
    def active(self) -> bool:
        joints = self.joint_spacing_m > 0.0 and bool(self.joint_amplitude_mps2)
        return self.enabled and (any(f.amplitude_mps2 for f in self.features) or joints)


@dataclass(frozen=True, slots=True)
class SecondBoard:
    """A second board on the same bus and train (devices.emulator.two_boards): its own BASE,
    sensors, board and random draws; the train's motion and its one odometer are shared
    (the scenario's board sends SPEED_REF, this one does not)."""

    base_id: int
    seed: int | None = None  # its own draws (None: the scenario's seed + 1)
    offset_m: float = 0.0  # its distance ahead (+) of the first board along the train
    sample_rate_hz: int = DEFAULT_SAMPLE_RATE_HZ
    channels: tuple[ChannelModel, ChannelModel, ChannelModel] = (
        ChannelModel(30.0),
        ChannelModel(0.0),
        ChannelModel(-30.0),
    )
    board: BoardModel = field(default_factory=lambda: BoardModel())
    counter0: int = 0
    board_time0_ticks: int = 0


@dataclass(frozen=True, slots=True)
class Fault:
    index: int  # 1-based position in [[faults]]
    kind: str
    target: int | str  # 1..3, "adc", "status", "speed", "bus" or "uart"
    start_s: float
    end_s: float
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def label(self) -> str:
        where = f"ch{self.target}" if isinstance(self.target, int) else self.target
        return f"#{self.index} {self.kind} {where} {self.start_s:g}-{self.end_s:g} s"


def _nominal_channels() -> tuple[ChannelModel, ChannelModel, ChannelModel]:
    a1, a2, a3 = NOMINAL_ANGLES_DEG
    return ChannelModel(a1), ChannelModel(a2), ChannelModel(a3)


@dataclass(frozen=True, slots=True)
class Scenario:
    seed: int = 0
    duration_s: float = 60.0
    sample_rate_hz: int = DEFAULT_SAMPLE_RATE_HZ
    base_id: int = DEFAULT_BASE
    g: float = G0
    speed_ref: bool = True
    initial_speed_mps: float = 0.0
    initial_position_m: float = 0.0
    vertical_curve_m: float = 50.0
    vertical_curve_accel: bool = True  # add v^2/R normal to the track on vertical curves
    jerk_mps3: float = 0.0  # ramp limit of the acceleration between phases; 0 = steps
    counter0: int = 0
    board_time0_ticks: int = 0
    start_time_s: float = 0.0
    description: str = ""
    track: tuple[TrackSegment, ...] = ()
    train: tuple[TrainPhase, ...] = ()
    channels: tuple[ChannelModel, ChannelModel, ChannelModel] = field(
        default_factory=_nominal_channels
    )
    board: BoardModel = field(default_factory=BoardModel)
    odometer: OdometerModel = field(default_factory=OdometerModel)
    vibration: VibrationModel = field(default_factory=VibrationModel)
    body_pitch: BodyPitchModel = field(default_factory=BodyPitchModel)
    standstill: StandstillModel = field(default_factory=StandstillModel)
    body_modes: BodyModesModel = field(default_factory=BodyModesModel)
    track_irregularity: IrregularityModel = field(default_factory=IrregularityModel)
    second_board: SecondBoard | None = None  # two boards on one bus, one odometer
    faults: tuple[Fault, ...] = ()
    source: str = "<defaults>"  # file name for messages
    path: str = ""  # the file it was loaded from ("" when parsed from text)

    @property
    def n_samples(self) -> int:
        """Sampling instants in the run: t = n / rate for 0 <= t < duration."""
        return math.ceil(self.duration_s * self.sample_rate_hz - 1e-9)

    def with_changes(self, **changes: Any) -> Scenario:
        return replace(self, **changes)


# --------------------------------------------------------------------------- validation


def _parse_track(file: str, items: list[Any]) -> tuple[TrackSegment, ...]:
    out = []
    for i, item in enumerate(items, 1):
        t = Table(file, f"track[{i}]", item)
        t.require("length_m", "every segment needs a length")
        length = t.num("length_m", 0.0, 0.0, 1e7, lo_open=True)
        grad = t.num("gradient_permil", 0.0, -500.0, 500.0)
        curve = t.num("vertical_curve_m", 0.0, 0.0, 1e4) if t.has("vertical_curve_m") else None
        t.done()
        out.append(TrackSegment(length, grad, curve))
    return tuple(out)


def _parse_train(file: str, items: list[Any]) -> tuple[TrainPhase, ...]:
    out = []
    for i, item in enumerate(items, 1):
        t = Table(file, f"train[{i}]", item)
        t.require("duration_s", "every phase needs a duration")
        dur = t.num("duration_s", 0.0, 0.0, 1e6, lo_open=True)
        acc = t.num("accel_mps2", 0.0, -10.0, 10.0)
        rev = t.flag("allow_reverse", False)
        jerk = t.num("jerk_mps3", 0.0, 0.0, 100.0) if t.has("jerk_mps3") else None
        t.done()
        out.append(TrainPhase(dur, acc, rev, jerk))
    return tuple(out)


def _parse_channels(file: str, items: list[Any]) -> tuple[ChannelModel, ChannelModel, ChannelModel]:
    if not items:
        return _nominal_channels()
    if len(items) != 3:
        raise ConfigError(
            f"{file}: channels: expected exactly three [[channels]] tables (ch1..ch3), "
            f"got {len(items)}"
        )
    out = []
    for i, (item, nominal) in enumerate(zip(items, NOMINAL_ANGLES_DEG, strict=True), 1):
        t = Table(file, f"channels[{i}]", item)
        out.append(
            ChannelModel(
                angle_deg=t.num("angle_deg", nominal, -90.0, 90.0),
                bias_mps2=t.num("bias_mps2", 0.0, -20.0, 20.0),
                scale_error=t.num("scale_error", 0.0, -0.5, 0.5),
                noise_mps2=t.num("noise_mps2", 0.0, 0.0, 20.0),
                vibration_mps2=t.num("vibration_mps2", 0.0, 0.0, 100.0),
                vibration_hz=t.num("vibration_hz", 0.0, 0.0, 100_000.0),
                vibration_phase_deg=t.num("vibration_phase_deg", 0.0, -360.0, 360.0),
                bias_tempco_mps2_per_k=t.num("bias_tempco_mps2_per_k", 0.0, -1.0, 1.0),
                bias_walk_mps2_per_sqrt_s=t.num("bias_walk_mps2_per_sqrt_s", 0.0, 0.0, 1.0),
                thermal_lag_s=t.num("thermal_lag_s", 0.0, 0.0, 1e6),
            )
        )
        t.done()
    angles = [c.angle_deg for c in out]
    if len(set(angles)) < 3:
        raise ConfigError(f"{file}: channels: the three angle_deg values must differ, got {angles}")
    return out[0], out[1], out[2]


def _parse_board(file: str, value: Any, rate: int) -> BoardModel:
    t = Table(file, "board", value)
    b = BoardModel(
        temperature_c=t.integer("temperature_c", 35, -128, 127),
        temperature_end_c=(
            t.num("temperature_end_c", 35.0, -128.0, 127.0) if t.has("temperature_end_c") else None
        ),
        temperature_tau_s=t.num("temperature_tau_s", 900.0, 0.0, 1e6, lo_open=True),
        station_cooling_k=t.num("station_cooling_k", 0.0, -50.0, 50.0),
        supply_v=t.num("supply_v", 24.0, 0.0, 25.5),
        errors0=t.integer("errors0", 0, 0, 255),
        status_counter0=t.integer("status_counter0", 0, 0, 255),
        latency_us=t.integer("latency_us", 100, 0, 100_000),
        frame_gap_us=t.integer("frame_gap_us", 250, 1, 10_000),
        status_offset_us=t.integer("status_offset_us", 500, 0, 99_999),
        antialias_filter=t.flag("antialias_filter", True),
    )
    t.done()
    # The bus must have room for everything, or send times would fall further behind forever.
    load = b.frame_gap_us * (3 * rate + 10 + 50) / 1e6
    if load >= 0.95:
        raise t.error(
            "frame_gap_us",
            f"{b.frame_gap_us} us per frame at {rate} Hz needs {load:.0%} of the bus (max 95%)",
        )
    return b


def _parse_odometer(file: str, value: Any) -> OdometerModel:
    t = Table(file, "odometer", value)
    o = OdometerModel(
        time0_ticks=t.integer("time0_ticks", 0, 0, 65535),
        drift_ppm=t.num("drift_ppm", 0.0, -100_000.0, 100_000.0),
        offset_s=t.num("offset_s", 0.0037, 0.0, 0.02),
        noise_mps=t.num("noise_mps", 0.0, 0.0, 10.0),
        lag_s=t.num("lag_s", 0.0, 0.0, 10.0),
        counter0=t.integer("counter0", 0, 0, 255),
        resolution_mps=t.num("resolution_mps", 0.0, 0.0, 10.0),
        slide_depth_mps=t.num("slide_depth_mps", 0.0, 0.0, 50.0),
        slide_period_s=t.num("slide_period_s", 1.2, 0.0, 60.0, lo_open=True),
        slide_min_decel_mps2=t.num("slide_min_decel_mps2", 0.3, 0.0, 10.0),
        slip_depth_mps=t.num("slip_depth_mps", 0.0, 0.0, 50.0),
        slip_period_s=t.num("slip_period_s", 1.0, 0.0, 60.0, lo_open=True),
        slip_min_accel_mps2=t.num("slip_min_accel_mps2", 0.3, 0.0, 10.0),
        wsp_jitter=t.num("wsp_jitter", 0.0, 0.0, 1.0),
        low_adhesion_start_s=t.num("low_adhesion_start_s", 0.0, 0.0, None),
        low_adhesion_end_s=(
            t.num("low_adhesion_end_s", 0.0, 0.0, None) if t.has("low_adhesion_end_s") else None
        ),
        wheel_diameter_error=t.num("wheel_diameter_error", 0.0, -0.05, 0.05),
    )
    t.done()
    if o.low_adhesion_end_s is not None and o.low_adhesion_end_s <= o.low_adhesion_start_s:
        raise t.error(
            "low_adhesion_end_s",
            f"must be > low_adhesion_start_s ({o.low_adhesion_start_s:g}), "
            f"got {o.low_adhesion_end_s!r}",
        )
    return o


def _parse_vibration(file: str, value: Any, rate: int) -> VibrationModel:
    t = Table(file, "vibration", value)
    nyquist = rate / 2.0
    v = VibrationModel(
        vertical_mps2=t.num("vertical_mps2", 0.0, 0.0, 50.0),
        longitudinal_mps2=t.num("longitudinal_mps2", 0.0, 0.0, 50.0),
        frequency_hz=t.num("frequency_hz", 2.5, 0.0, nyquist, lo_open=True),
        longitudinal_phase_deg=t.num("longitudinal_phase_deg", 90.0, -360.0, 360.0),
        broadband_vertical_mps2=t.num("broadband_vertical_mps2", 0.0, 0.0, 50.0),
        broadband_longitudinal_mps2=t.num("broadband_longitudinal_mps2", 0.0, 0.0, 50.0),
        broadband_low_hz=t.num("broadband_low_hz", 0.5, 0.0, nyquist),
        broadband_high_hz=t.num("broadband_high_hz", 20.0, 0.0, nyquist, lo_open=True),
        reference_speed_mps=t.num("reference_speed_mps", 20.0, 0.0, 150.0, lo_open=True),
        speed_exponent=t.num("speed_exponent", 1.0, 0.0, 4.0, lo_open=True),
    )
    t.done()
    if v.broadband_high_hz <= v.broadband_low_hz:
        raise t.error(
            "broadband_high_hz",
            f"must be > broadband_low_hz ({v.broadband_low_hz:g}), got {v.broadband_high_hz!r}",
        )
    return v


def _parse_body_pitch(file: str, value: Any) -> BodyPitchModel:
    t = Table(file, "body_pitch", value)
    m = BodyPitchModel(
        enabled=t.flag("enabled", True),
        compliance_deg_per_mps2=t.num("compliance_deg_per_mps2", 0.05, -2.0, 2.0),
        frequency_hz=t.num("frequency_hz", 1.2, 0.1, 20.0),
        damping_ratio=t.num("damping_ratio", 0.25, 0.01, 0.99),
        static_deg=t.num("static_deg", 0.0, -5.0, 5.0),
        load_step_deg=t.num("load_step_deg", 0.02, 0.0, 2.0),
        min_dwell_s=t.num("min_dwell_s", 10.0, 0.0, 1e6, lo_open=True),
    )
    t.done()
    return m


def _parse_standstill(file: str, value: Any, rate: int) -> StandstillModel:
    t = Table(file, "standstill", value)
    nyquist = rate / 2.0
    m = StandstillModel(
        enabled=t.flag("enabled", True),
        hvac_mps2=t.num("hvac_mps2", 0.01, 0.0, 5.0),
        hvac_hz=t.num("hvac_hz", 14.0, 0.0, nyquist, lo_open=True),
        door_mps2=t.num("door_mps2", 0.1, 0.0, 10.0),
        door_hz=t.num("door_hz", 8.0, 0.0, nyquist, lo_open=True),
        door_decay_s=t.num("door_decay_s", 0.3, 0.0, 10.0, lo_open=True),
        boarding_rate_hz=t.num("boarding_rate_hz", 0.5, 0.0, 50.0),
        boarding_step_deg=t.num("boarding_step_deg", 0.002, 0.0, 1.0),
    )
    t.done()
    return m


def _parse_body_modes(file: str, value: Any) -> BodyModesModel:
    t = Table(file, "body_modes", value)
    modes: dict[str, ModeModel] = {}
    for name, default in MODE_DEFAULTS.items():
        m = Table(file, f"body_modes.{name}", t.raw(name, {}))
        unit = MODE_UNITS[name]
        modes[name] = ModeModel(
            rms=m.num(unit, default.rms, 0.0, 10.0),
            frequency_hz=m.num("frequency_hz", default.frequency_hz, 0.0, 100.0, lo_open=True),
            damping=m.num("damping", default.damping, 0.0, 0.5, lo_open=True),
        )
        m.done()
    b = BodyModesModel(
        enabled=t.flag("enabled", True),
        bounce=modes["bounce"],
        pitch=modes["pitch"],
        bending=modes["bending"],
        lever_m=t.num("lever_m", 0.0, -20.0, 20.0),
        reference_speed_mps=t.num("reference_speed_mps", 20.0, 0.0, 150.0, lo_open=True),
        speed_exponent=t.num("speed_exponent", 1.0, 0.0, 4.0, lo_open=True),
    )
    t.done((*MODE_DEFAULTS, "enabled", "lever_m", "reference_speed_mps", "speed_exponent"))
    return b


MAX_FEATURES = 1024
MAX_AXLES = 16


def _parse_irregularity(file: str, value: Any) -> IrregularityModel:
    t = Table(file, "track_irregularity", value)
    freq = t.num("frequency_hz", 9.0, 0.0, 200.0, lo_open=True)
    damping = t.num("damping", 0.1, 0.0, 0.9, lo_open=True)
    items = t.array("features")
    if len(items) > MAX_FEATURES:
        raise t.error("features", f"at most {MAX_FEATURES} features, got {len(items)}")
    feats = []
    for i, item in enumerate(items, 1):
        f = Table(file, f"track_irregularity.features[{i}]", item)
        f.require("position_m", "where on the line the feature is")
        feats.append(
            TrackFeature(
                position_m=f.num("position_m", None, -1e7, 1e7),
                amplitude_mps2=f.num("amplitude_mps2", 0.5, -20.0, 20.0),
                frequency_hz=f.num("frequency_hz", freq, 0.0, 200.0, lo_open=True),
                damping=f.num("damping", damping, 0.0, 0.9, lo_open=True),
            )
        )
        f.done()
    axles = t.raw("axles_m", [0.0])
    if (
        not isinstance(axles, list)
        or not 1 <= len(axles) <= MAX_AXLES
        or not all(isinstance(a, int | float) and not isinstance(a, bool) for a in axles)
        or not all(math.isfinite(a) and abs(a) <= 50.0 for a in axles)
    ):
        raise t.error("axles_m", f"expected 1..{MAX_AXLES} distances in [-50, 50] m, got {axles!r}")
    m = IrregularityModel(
        enabled=t.flag("enabled", True),
        features=tuple(feats),
        joint_spacing_m=t.num("joint_spacing_m", 0.0, 0.0, 1e4),
        joint_start_m=t.num("joint_start_m", 0.0, -1e7, 1e7),
        joint_amplitude_mps2=t.num("joint_amplitude_mps2", 0.3, -20.0, 20.0),
        joint_spread=t.num("joint_spread", 0.5, 0.0, 1.0),
        frequency_hz=freq,
        damping=damping,
        axles_m=tuple(float(a) for a in axles),
        reference_speed_mps=t.num("reference_speed_mps", 20.0, 0.0, 150.0, lo_open=True),
        speed_exponent=t.num("speed_exponent", 1.0, 0.0, 4.0, lo_open=True),
        track_seed=t.integer("track_seed", 0, 0, (1 << 63) - 1),
    )
    if 0.0 < m.joint_spacing_m < 1.0:
        raise t.error("joint_spacing_m", f"must be 0 or at least 1 m, got {m.joint_spacing_m!r}")
    t.done(
        (
            "enabled",
            "features",
            "joint_spacing_m",
            "joint_start_m",
            "joint_amplitude_mps2",
            "joint_spread",
            "frequency_hz",
            "damping",
            "axles_m",
            "reference_speed_mps",
            "speed_exponent",
            "track_seed",
        )
    )
    return m


def _ranges_overlap(a: int, b: int) -> bool:
    return abs(a - b) <= 3


def _parse_second_board(
    file: str,
    value: Any,
    base: int,
    rate: int,
    a: BoardModel,
    channels: tuple[ChannelModel, ChannelModel, ChannelModel],
) -> SecondBoard | None:
    if value is None:
        return None
    t = Table(file, "second_board", value)
    t.require("base_id", "the second board's BASE, e.g. 0x200")
    b_base = t.integer("base_id", None, 0, 0x7FC)
    if b_base <= SPEED_REF_ID <= b_base + 3:
        raise t.error("base_id", f"0x{b_base:X}..0x{b_base + 3:X} would overlap SPEED_REF 0x180")
    if _ranges_overlap(base, b_base):
        raise t.error(
            "base_id", f"0x{b_base:X}..0x{b_base + 3:X} overlaps the first board's 0x{base:X}.."
        )
    b_rate = t.integer("sample_rate_hz", rate, 50, 1000)
    items = t.array("channels")
    sub = f"{file}: second_board" if file else "second_board"
    own = _parse_channels(sub, items) if items else channels  # default: the same build
    board_raw = t.raw("board", None)
    board = _parse_board(sub, board_raw, b_rate) if board_raw is not None else a
    load = (a.frame_gap_us * (3 * rate + 10 + 50) + board.frame_gap_us * (3 * b_rate + 10)) / 1e6
    if load >= 0.95:
        raise t.error(
            "sample_rate_hz", f"the two boards at {rate} and {b_rate} Hz need {load:.0%} of the bus"
        )
    m = SecondBoard(
        base_id=b_base,
        seed=t.integer("seed", None, 0, (1 << 63) - 1) if t.has("seed") else None,
        offset_m=t.num("offset_m", 0.0, -1000.0, 1000.0),
        sample_rate_hz=b_rate,
        channels=own,
        board=board,
        counter0=t.integer("counter0", 0, 0, 255),
        board_time0_ticks=t.integer("board_time0_ticks", 0, 0, 65535),
    )
    t.done()
    return m


_STATUS_BITS = {name: bit for bit, name in STATUS_BIT_NAMES.items()}


def _status_bits(t: Table, key: str) -> int:
    v = t.raw(key, FAULT_PARAMS["status"]["bits"])
    if isinstance(v, list):
        bits = 0
        for name in v:
            if not isinstance(name, str) or name.upper() not in _STATUS_BITS:
                raise t.error(
                    key,
                    f"unknown status bit {name!r} (expected names from "
                    f"{', '.join(_STATUS_BITS)} or an integer 1..255)",
                )
            bits |= _STATUS_BITS[name.upper()]
        if not bits:
            raise t.error(key, "names no bit")
        return bits
    if not is_integer(v):
        raise t.error(key, f"expected an integer 1..255 or a list of bit names, got {v!r}")
    t.check_range(key, v, 1, 255)
    return v


def _parse_target(t: Table, kind: str) -> int | str:
    t.require("channel", "1..3, or one of adc, status, speed, bus, uart")
    v: int | str = t.raw("channel")
    if kind in UART_KINDS:
        allowed: tuple[Any, ...] = ("uart",)
    elif kind in SIGNAL_KINDS:
        allowed = (1, 2, 3, "adc")
    else:
        allowed = (1, 2, 3, *CAN_TARGETS)
    if isinstance(v, bool) or v not in allowed:
        shown = ", ".join(str(a) for a in allowed)
        raise t.error("channel", f"{v!r} is not a target of a {kind!r} fault (expected {shown})")
    return v


def _parse_fault(file: str, i: int, item: Any, duration: float) -> Fault:
    t = Table(file, f"faults[{i}]", item)
    kind = t.raw("kind")
    if kind is None:
        raise t.error("kind", f"missing (one of {', '.join(FAULT_KINDS)})")
    if not isinstance(kind, str) or kind not in FAULT_PARAMS:
        raise t.error(
            "kind", f"unknown fault kind {kind!r} (expected one of {', '.join(FAULT_KINDS)})"
        )
    target = _parse_target(t, kind)
    start = t.num("start_s", 0.0, 0.0, None)
    if start >= duration:
        raise t.error("start_s", f"must be < duration_s ({duration:g}), got {start!r}")
    end = t.num("end_s", duration, 0.0, None)
    if end <= start:
        raise t.error("end_s", f"must be > start_s ({start:g}), got {end!r}")
    params: dict[str, Any] = {}
    for key, default in FAULT_PARAMS[kind].items():
        if key == "bits":
            params[key] = _status_bits(t, key)
        elif key == "code":
            params[key] = t.integer(key, 0, -(1 << 23), (1 << 23) - 1) if t.has(key) else None
        elif key == "probability":
            params[key] = t.num(key, default, 0.0, 1.0)
        elif key == "width_samples":
            params[key] = t.integer(key, default, 1, 10_000)
        elif key == "depth":
            params[key] = t.integer(key, default, 1, 1000)
        elif key == "burst_bytes":
            params[key] = t.integer(key, default, 1, 1024)
        elif key == "jump":
            params[key] = t.integer(key, default, -255, 255)
            if params[key] % 256 == 0:
                raise t.error(key, "must not be a multiple of 256 (that is no jump)")
        elif key == "rate_hz":  # at most one spike per sample at the ICD's top rate
            params[key] = t.num(key, default, 0.0, 1000.0)
        elif key == "amplitude_mps2" or key == "value_mps2" or key == "offset_mps2":
            params[key] = t.num(key, default, -1000.0, 1000.0)
        elif key == "rate_mps2_per_s":
            params[key] = t.num(key, default, -100.0, 100.0)
        else:  # pragma: no cover - every parameter above has a rule
            raise AssertionError(key)
    t.done((*_COMMON_FAULT_KEYS, *FAULT_PARAMS[kind]))
    if kind == "spike" and params["rate_hz"] * params["width_samples"] > MAX_SPIKE_DUTY:
        # wider and more frequent pulses would cover every sample many times over (and
        # cost rate x width additions per second of run)
        raise t.error(
            "rate_hz",
            f"x width_samples must be <= {MAX_SPIKE_DUTY:g} (spike samples per second at "
            f"the ICD's top rate), got {params['rate_hz']:g} x {params['width_samples']}",
        )
    return Fault(i, kind, target, start, end, params)


_TOP_KEYS = (
    "seed",
    "duration_s",
    "sample_rate_hz",
    "base_id",
    "g",
    "speed_ref",
    "initial_speed_mps",
    "initial_position_m",
    "vertical_curve_m",
    "vertical_curve_accel",
    "jerk_mps3",
    "counter0",
    "board_time0_ticks",
    "start_time_s",
    "description",
    "track",
    "train",
    "channels",
    "board",
    "odometer",
    "vibration",
    "body_pitch",
    "standstill",
    "body_modes",
    "track_irregularity",
    "second_board",
    "faults",
)


MAX_SPIKE_DUTY = 1000.0
"""Most spike samples per second a spike fault may ask for (rate_hz x width_samples)."""

MAX_FAULTS = 256
"""Most faults one scenario may list (each is a pass over the whole stream)."""


def _bounded(top: Table, key: str, most: int) -> list[Any]:
    items = top.array(key)
    if len(items) > most:
        raise top.error(key, f"at most {most} [[{key}]] tables, got {len(items)}")
    return items


def scenario_from_dict(data: Mapping[str, Any], source: str = "<dict>") -> Scenario:
    """Validate a parsed TOML document into a Scenario. Raises ConfigError naming the key."""
    top = Table(source, "", dict(data))
    top.done(_TOP_KEYS)
    seed = top.integer("seed", 0, 0, (1 << 63) - 1)
    duration = top.num("duration_s", 60.0, 0.0, MAX_DURATION_S, lo_open=True)
    rate = top.integer("sample_rate_hz", DEFAULT_SAMPLE_RATE_HZ, 50, 1000)
    base = top.integer("base_id", DEFAULT_BASE, 0, 0x7FC)
    if base <= SPEED_REF_ID <= base + 3:
        raise top.error("base_id", f"0x{base:X}..0x{base + 3:X} would overlap SPEED_REF 0x180")
    board = _parse_board(source, top.raw("board", {}), rate)
    channels = _parse_channels(source, top.array("channels"))
    sc = Scenario(
        seed=seed,
        duration_s=duration,
        sample_rate_hz=rate,
        base_id=base,
        g=top.num("g", G0, 1.0, 20.0),
        speed_ref=top.flag("speed_ref", True),
        initial_speed_mps=top.num("initial_speed_mps", 0.0, -150.0, 150.0),
        initial_position_m=top.num("initial_position_m", 0.0, -1e7, 1e7),
        vertical_curve_m=top.num("vertical_curve_m", 50.0, 0.0, 1e4),
        vertical_curve_accel=top.flag("vertical_curve_accel", True),
        jerk_mps3=top.num("jerk_mps3", 0.0, 0.0, 100.0),
        counter0=top.integer("counter0", 0, 0, 255),
        board_time0_ticks=top.integer("board_time0_ticks", 0, 0, 65535),
        start_time_s=top.num("start_time_s", 0.0, 0.0, 1e10),
        description=top.text("description", ""),
        track=_parse_track(source, top.array("track")),
        train=_parse_train(source, top.array("train")),
        channels=channels,
        board=board,
        odometer=_parse_odometer(source, top.raw("odometer", {})),
        vibration=_parse_vibration(source, top.raw("vibration", {}), rate),
        body_pitch=_parse_body_pitch(source, top.raw("body_pitch", {})),
        standstill=_parse_standstill(source, top.raw("standstill", {}), rate),
        body_modes=_parse_body_modes(source, top.raw("body_modes", {})),
        track_irregularity=_parse_irregularity(source, top.raw("track_irregularity", {})),
        second_board=_parse_second_board(
            source, top.raw("second_board"), base, rate, board, channels
        ),
        faults=tuple(
            _parse_fault(source, i, item, duration)
            for i, item in enumerate(_bounded(top, "faults", MAX_FAULTS), 1)
        ),
        source=source,
    )
    return sc


def parse_scenario(text: str, source: str = "<string>") -> Scenario:
    """Parse scenario TOML text (``source`` names it in error messages)."""
    return scenario_from_dict(parse_toml(text, source), source)


def resolve_scenario_path(name: str | Path) -> Path:
    """A path as given if it exists, else a built-in scenario by name (``demo`` -> demo.toml)."""
    found = path_or_packaged(name, SCENARIO_DIR)
    if found is None:
        known = ", ".join(builtin_scenarios())
        raise ConfigError(f"{name}: no such scenario file (built-in scenarios: {known})")
    return found


def builtin_scenarios() -> list[str]:
    return sorted(f.stem for f in SCENARIO_DIR.glob("*.toml"))


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file (or a built-in scenario by name)."""
    p = resolve_scenario_path(path)
    text = read_text_file(p, "scenario")
    return replace(parse_scenario(text, p.name), path=str(p))


def calibration_toml(sc: Scenario) -> str:
    """A bench calibration config (bench.config format) matching this board as built: its
    calibration sheet (ICD 1.1 and 3), taken at the run's start temperature.

    Angles, scales and offsets are the true ones (a = (code - offset) * scale undoes the
    scale error and the bias), so a bench run against the emulator with this config
    isolates fusion errors from calibration errors; what remains is the bias's drift with
    temperature, as on a real board.
    """
    lines = [
        f"# calibration of the virtual board of {printable(sc.source)}",
        "[board]",
        f"base_id = 0x{sc.base_id:X}",
        f"sample_rate_hz = {sc.sample_rate_hz}",
        "",
    ]
    for c in sc.channels:
        scale = NOMINAL_SCALE / (1.0 + c.scale_error)
        offset = c.bias_mps2 / NOMINAL_SCALE
        lines += [
            "[[channels]]",
            f"angle_deg = {c.angle_deg!r}",
            f"scale = {scale!r}",
            f"offset = {offset!r}",
            "",
        ]
    lines += ["[fusion]", f"g = {sc.g!r}", ""]
    return "\n".join(lines)
