"""The virtual board's one world-to-sensor engine: sampling instants -> world -> sensor values
-> the board's own faults -> ADC codes -> nominal ADC frames, and the truth of each instant.

Both the whole run (:func:`devices.emulator.simulation.simulate`, one block of every
instant) and the chunked run (:func:`devices.emulator.stream.simulate_chunks`, consecutive
blocks) take their samples from :class:`Engine`, so they cannot disagree. A block of
instants [a, b) depends only on the instants and on what the engine carries from the
blocks before it: each noise source draws from its own generator in sample order (numpy's
generators give the same numbers drawn in pieces as in one call), a spike fault's
positions are planned for its whole window up front and a stuck fault keeps the code it
repeats. Everything else is a function of the instant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.antialias import gain_of
from devices.emulator.board import FrameSet, adc_frames
from devices.emulator.body_modes import BodyModes
from devices.emulator.body_pitch import BodyPitch, pitched_specific_force, scenario_stations
from devices.emulator.irregularity import rings
from devices.emulator.motion import scenario_motion
from devices.emulator.scenario import Fault, Scenario
from devices.emulator.standstill import plan as standstill_plan
from devices.emulator.standstill import standstill_accel
from devices.emulator.stream_carry import Spikes
from devices.emulator.thermal import Thermal
from devices.emulator.vibration import body_vibration
from devices.emulator.world import (
    body_specific_force,
    curve_normal_accel,
    gradient_profile,
    gradient_slope,
    quantise,
    sensor_output,
    specific_force,
)
from protocol.layout import STATUS_OVR

TRUTH_DTYPE = np.dtype(
    [
        ("time_s", "<f8"),  # sampling instant, same time base as the frames' t
        ("counter", "<i8"),  # unwrapped sample counter: counter0 + n (wire counter = this % 256)
        ("gradient_permil", "<f8"),  # at the train's position
        ("accel_mps2", "<f8"),  # d(speed)/dt along the track
        ("speed_mps", "<f8"),
        ("position_m", "<f8"),
        ("body_pitch_deg", "<f8"),  # the car body's pitch on its suspension, nose up
    ]
)
TRUTH_COLUMNS: tuple[str, ...] = TRUTH_DTYPE.names or ()


def sample_us(rate_hz: int, idx: np.ndarray) -> np.ndarray:
    """Sampling instants n / rate in whole microseconds (relative to the run's start)."""
    return (idx * 1_000_000 + rate_hz // 2) // rate_hz


@dataclass(slots=True)
class Block:
    """Sampling instants [a, a + m) of the run: their nominal ADC frames (``seq`` is the
    sample index n), the sample mask of each board fault that acted on them (local
    indices) and their truth rows."""

    a: int
    sample_us: np.ndarray
    adc: FrameSet
    hit: dict[int, np.ndarray]
    truth: np.ndarray


class Engine:
    """World -> sensors -> board -> ADC frames of consecutive blocks of sampling instants.

    ``values=False`` skips the sensors (codes 0, no truth): a cheap pass that only needs
    the frames' identities and times (the chunked run counts random draws with it)."""

    def __init__(self, sc: Scenario, *, values: bool = True) -> None:
        self.sc, self.values = sc, values
        self.rate = sc.sample_rate_hz
        self.n = sc.n_samples
        self.start_us = fx.to_us(sc.start_time_s)
        self.jumps = [f for f in sc.faults if f.kind == "counter_jump"]
        seed = sc.seed
        # one generator per noise source and per fault, drawn in sample order
        self.noise = [fx.rng_for(seed, fx.LAYER_NOISE, i + 1) for i in range(len(sc.channels))]
        self.fault_rng = {
            f.index: fx.rng_for(seed, fx.LAYER_FAULT, f.index)
            for f in sc.faults
            if f.kind == "spike"
        }
        self.spikes = self._spike_plans() if values else {}
        stations = scenario_stations(sc)
        self.still = standstill_plan(sc, stations) if sc.standstill.enabled else None
        boarding = (self.still.board_t, self.still.board_deg) if self.still else None
        self.pitch = BodyPitch(sc, stations, boarding) if sc.body_pitch.enabled else None
        self.modes = (
            BodyModes.draw(sc.body_modes, fx.rng_for(seed, fx.LAYER_BODY_MODES))
            if sc.body_modes.active
            else None
        )
        self.thermal = Thermal(sc, stations)
        # each channel's bias random walk: its own generator, summed in sample order
        self.walk = [fx.rng_for(seed, fx.LAYER_BIAS_WALK, i + 1) for i in range(len(sc.channels))]
        self.walk_at = np.zeros(len(sc.channels))  # the walk at the last sample so far
        self.rings = rings(sc) if sc.track_irregularity.active and values else None
        self.stuck_carry: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.next = 0  # the first instant of the next block

    def block(self, a: int, b: int) -> Block:
        """Instants [a, b); blocks must come in order, each starting where the last ended."""
        if a != self.next:
            raise ValueError(f"blocks must follow one another: expected {self.next}, got {a}")
        self.next = b
        sc = self.sc
        idx = np.arange(a, b, dtype=np.int64)
        us = sample_us(self.rate, idx)
        m = len(idx)
        hit: dict[int, np.ndarray] = {}
        if self.values:
            codes, status = self._board(idx, us, hit)
        else:
            codes = np.zeros((3, m), dtype=np.int64)
            status = np.zeros((3, m), dtype=np.uint8)
        counters = np.tile(sc.counter0 + idx, (3, 1))
        for f in self.jumps:
            win = fx.in_window(us, f)
            for ch in fx.target_channels(f):
                counters[ch - 1, win] += f.params["jump"]
        ticks = sc.board_time0_ticks + (idx * 10_000 + self.rate // 2) // self.rate
        adc = adc_frames(sc.base_id, us, sc.board.latency_us, counters, codes, status, ticks)
        adc.seq += a
        truth = self._truth(idx, us) if self.values else np.zeros(0, dtype=TRUTH_DTYPE)
        return Block(a, us, adc, hit, truth)

    # -- world and sensors -----------------------------------------------------------------
    def _sensors(self, us: np.ndarray) -> np.ndarray:
        """(3, m) sensor values (m/s^2) at these instants, before the board's faults."""
        sc = self.sc
        t = us / 1e6
        motion = scenario_motion(sc, t)
        grad = gradient_profile(sc.track, sc.vertical_curve_m, motion.position_m)
        filtered = sc.board.antialias_filter
        rate = float(self.rate) if filtered else None
        body_x, body_z = body_vibration(
            sc.vibration, t, motion.speed_mps, fx.rng_for(sc.seed, fx.LAYER_VIBRATION), rate
        )
        if sc.vertical_curve_accel:
            slope = gradient_slope(sc.track, sc.vertical_curve_m, motion.position_m)
            body_z += curve_normal_accel(motion.speed_mps, grad, slope)
        if self.still is not None:
            still_x, still_z = standstill_accel(sc, self.still, t, self.rate)
            body_x, body_z = body_x + still_x, body_z + still_z
        if self.rings is not None:  # the line's joints and switches
            body_z = body_z + self.rings.at(t, rate)
        extra = (
            sc.vibration.active
            or sc.vertical_curve_accel
            or self.still is not None
            or self.rings is not None
        )
        pitch = self.pitch.deg(t) if self.pitch is not None else None
        if self.modes is not None:  # bounce and bending along z, the pitch mode turns the axes
            mode_z, mode_pitch = self.modes.felt(t, motion.speed_mps, rate)
            body_z += mode_z
            pitch = mode_pitch if pitch is None else pitch + mode_pitch
        values = np.empty((3, len(us)), dtype=np.float64)
        for i, ch in enumerate(sc.channels):
            if pitch is not None:  # the board sits on the pitching body
                ideal = pitched_specific_force(
                    motion.accel_mps2, grad, sc.g, ch.angle_deg, pitch, body_x, body_z
                )
            elif extra:
                ideal = body_specific_force(
                    motion.accel_mps2, grad, sc.g, ch.angle_deg, body_x, body_z
                )
            else:
                ideal = specific_force(motion.accel_mps2, grad, sc.g, ch.angle_deg)
            h = gain_of(ch.vibration_hz, self.rate, filtered)
            rise = (
                self.thermal.channel(i, t) - sc.board.temperature_c
                if ch.bias_tempco_mps2_per_k
                else None  # no drift to compute
            )
            values[i] = sensor_output(ideal, ch, t, self.noise[i], rise, h)
        return values

    def _add_walk(self, values: np.ndarray, first: bool) -> None:
        """Each channel's bias random walk, b_n = q sqrt(1/rate) (z_1 + ... + z_n): zero at
        the run's first sample (the sheet's bias), variance q^2 t. Summed with the carry in
        front, in order, so any split into blocks gives the whole run's sums bit for bit."""
        step = math.sqrt(1.0 / self.rate)
        for i, ch in enumerate(self.sc.channels):
            q = ch.bias_walk_mps2_per_sqrt_s
            if not q:
                continue
            dz = np.asarray(q * step * self.walk[i].standard_normal(values.shape[1]))
            if first:
                dz[0] = 0.0
            walk = np.cumsum(np.concatenate(([self.walk_at[i]], dz)))[1:]
            self.walk_at[i] = walk[-1]
            values[i] += walk

    def _truth(self, idx: np.ndarray, us: np.ndarray) -> np.ndarray:
        sc = self.sc
        motion = scenario_motion(sc, us / 1e6)
        truth = np.zeros(len(idx), dtype=TRUTH_DTYPE)
        truth["time_s"] = (self.start_us + us) / 1e6
        truth["counter"] = sc.counter0 + idx
        truth["gradient_permil"] = gradient_profile(
            sc.track, sc.vertical_curve_m, motion.position_m
        )
        truth["accel_mps2"] = motion.accel_mps2
        truth["speed_mps"] = motion.speed_mps
        truth["position_m"] = motion.position_m
        if self.pitch is not None:
            truth["body_pitch_deg"] = self.pitch.deg(us / 1e6)
        return truth

    # -- the board's own faults (layer 1) --------------------------------------------------
    def _board(
        self, idx: np.ndarray, us: np.ndarray, hit: dict[int, np.ndarray]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sensor values -> codes and status of these instants, board faults applied."""
        sc = self.sc
        values = self._sensors(us)
        m = len(idx)
        a = int(idx[0]) if m else 0
        if m:
            self._add_walk(values, a == 0)
        for f in sc.faults:
            if f.kind in ("drift", "saturate"):
                rows = fx.apply_value_fault(values, f, us)
                hit[f.index] = _mask(rows, m)
            elif f.kind == "spike":
                mask = np.zeros(m, dtype=bool)
                width, amp = f.params["width_samples"], f.params["amplitude_mps2"]
                for plan in self.spikes[f.index]:
                    at, value = plan.pulses(a, m, width, amp)
                    np.add.at(values[plan.channel - 1], at, value)  # in order, as k by k
                    mask[at] = True
                hit[f.index] = mask
        codes, over = quantise(values)
        status = np.where(over, STATUS_OVR, 0).astype(np.uint8)
        for f in sc.faults:
            if f.kind == "stuck":
                hit[f.index] = self._stuck(f, codes, status, us, a)
        for f in sc.faults:
            if f.kind == "status":
                hit[f.index] = _mask(fx.apply_status_bits(status, f, us), m)
        return codes, status

    def _spike_plans(self) -> dict[int, list[Spikes]]:
        """Per spike fault, per channel, the spike positions over the whole window (as bits:
        1/8 byte per sample); their signs are drawn as blocks need them (they come after the
        positions from the same generator, in position order)."""
        plans: dict[int, list[Spikes]] = {}
        for f in self.sc.faults:
            if f.kind != "spike":
                continue
            rng = self.fault_rng[f.index]
            i0 = self.first_sample_at(fx.to_us(f.start_s))
            length = max(0, self.first_sample_at(fx.to_us(f.end_s)) - i0)
            plans[f.index] = []
            for ch in fx.target_channels(f):
                if length == 0:
                    continue
                expected = f.params["rate_hz"] * length / self.rate
                size = min(rng.poisson(expected), length)
                bits = np.zeros(length, dtype=bool)
                for done in range(0, size, 1 << 20):  # rng.choice(idx, size), in pieces
                    bits[rng.integers(0, length, size=min(1 << 20, size - done))] = True
                count = int(np.count_nonzero(bits))
                signs = np.random.Generator(type(rng.bit_generator)())
                signs.bit_generator.state = rng.bit_generator.state
                for done in range(0, count, 1 << 20):  # past the signs: the next channel's
                    rng.random(min(1 << 20, count - done))  # (advance() would drop a
                    # buffered half-word of the position draws)
                plans[f.index].append(Spikes(ch, i0, length, np.packbits(bits), signs))
        return plans

    def first_sample_at(self, us: int) -> int:
        """The first sample index whose instant is >= ``us`` (n if none)."""
        lo, hi = 0, self.n
        while lo < hi:
            mid = (lo + hi) // 2
            if int(sample_us(self.rate, np.array([mid]))[0]) < us:
                lo = mid + 1
            else:
                hi = mid
        return lo

    def _stuck(
        self, f: Fault, codes: np.ndarray, status: np.ndarray, us: np.ndarray, a: int
    ) -> np.ndarray:
        """The ADC register stops updating: it repeats the value at the sample before the
        window (or the first), taken in the block that holds it, or the fault's ``code``."""
        m = len(us)
        first = self.first_sample_at(fx.to_us(f.start_s))
        end = self.first_sample_at(fx.to_us(f.end_s))
        if first >= end:
            return np.zeros(m, dtype=bool)
        src = max(first - 1, 0)
        chans = [ch - 1 for ch in fx.target_channels(f)]
        if a <= src < a + m:
            self.stuck_carry[f.index] = (
                codes[chans, src - a].copy(),
                status[chans, src - a].copy(),
            )
        win = fx.in_window(us, f)
        if not win.any():
            return win
        held_codes, held_status = self.stuck_carry[f.index]
        for j, ch in enumerate(chans):
            code = f.params["code"]
            codes[ch, win] = held_codes[j] if code is None else code
            status[ch, win] = held_status[j] if code is None else 0
        return win


def _mask(rows: np.ndarray, m: int) -> np.ndarray:
    out = np.zeros(m, dtype=bool)
    out[rows] = True
    return out


__all__ = ["TRUTH_COLUMNS", "TRUTH_DTYPE", "Block", "Engine", "sample_us"]
