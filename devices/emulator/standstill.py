"""What a standing car still feels (issue 25): the HVAC's hum, the doors' jolts and the
passengers boarding. A real car is never exactly still, so an estimator must stay bounded
on a train at rest.

* HVAC hum: a tone at ``hvac_hz``, amplitude ``hvac_mps2`` normal to the track and half of
  it along the track (phases seeded), running or standing: the HVAC is always on.
* Doors: at every station (the stops of :func:`devices.emulator.body_pitch.stations`) the
  doors open at 20 % and close at 80 % of the dwell; each time the body rings at
  ``door_hz``: ``door_mps2`` e^(-tau / door_decay_s) sin(2 pi door_hz tau) along the track
  (a seeded sign per event) and half of it normal to the track.
* Boarding: while the doors are open passengers step on at ``boarding_rate_hz`` (Poisson),
  each shifting the body's pitch by a normal draw of standard deviation
  ``boarding_step_deg``; the body pitch's suspension turns each step into a decaying sway.

All of it is planned at the start from its own generator and is a pure function of time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from devices.emulator import faults as fx
from devices.emulator.antialias import gain_of
from devices.emulator.scenario import Scenario

DOOR_RING_DECAYS = 12.0
"""A door's ringing is dropped after this many decay times (e^-12 = 6e-6 of its peak)."""


@dataclass(frozen=True, slots=True)
class Plan:
    """The standstill events of one run, drawn once."""

    hvac_phase: tuple[float, float]  # (along, normal to the track), rad
    door_t: np.ndarray  # the door events' times (s)
    door_sign: np.ndarray  # +1 / -1 per event
    board_t: np.ndarray  # passengers' boarding times (s), sorted
    board_deg: np.ndarray  # each one's pitch step (deg)


def plan(sc: Scenario, stations: list[tuple[float, float]]) -> Plan:
    """Draw the run's standstill events: per station its passengers (count, times, steps),
    then the doors' signs, then the HVAC's phases."""
    m = sc.standstill
    rng = fx.rng_for(sc.seed, fx.LAYER_STANDSTILL)
    times: list[np.ndarray] = []
    steps: list[np.ndarray] = []
    doors: list[float] = []
    for t0, t1 in stations:
        opened, closed = t0 + 0.2 * (t1 - t0), t0 + 0.8 * (t1 - t0)
        n = int(rng.poisson(m.boarding_rate_hz * (closed - opened)))
        times.append(np.sort(rng.uniform(opened, closed, n)))
        steps.append(m.boarding_step_deg * rng.standard_normal(n))
        doors += [opened, closed]
    signs = np.where(rng.random(len(doors)) < 0.5, -1.0, 1.0)
    phase = 2.0 * math.pi * rng.random(2)
    return Plan(
        (float(phase[0]), float(phase[1])),
        np.array(doors, dtype=np.float64),
        signs,
        np.concatenate(times) if times else np.zeros(0),
        np.concatenate(steps) if steps else np.zeros(0),
    )


def standstill_accel(
    sc: Scenario, p: Plan, t: np.ndarray, rate_hz: float
) -> tuple[np.ndarray, np.ndarray]:
    """(x, z): the HVAC's and the doors' body acceleration along and normal to the track
    (m/s^2) at run times t (sorted), as the board's anti-alias filter passes them (each at
    the gain of its frequency; a door's ring is narrow: 1 / (pi door_decay_s) Hz wide)."""
    m = sc.standstill
    t = np.asarray(t, dtype=np.float64)
    on = sc.board.antialias_filter
    w = 2.0 * math.pi * m.hvac_hz
    hvac = m.hvac_mps2 * gain_of(m.hvac_hz, rate_hz, on)
    x = 0.5 * hvac * np.sin(w * t + p.hvac_phase[0])
    z = hvac * np.sin(w * t + p.hvac_phase[1])
    if m.door_mps2:
        door = m.door_mps2 * gain_of(m.door_hz, rate_hz, on)
        horizon = DOOR_RING_DECAYS * m.door_decay_s
        wd = 2.0 * math.pi * m.door_hz
        for td, sign in zip(p.door_t, p.door_sign, strict=True):
            lo, hi = np.searchsorted(t, [td, td + horizon])
            if lo == hi:
                continue
            tau = t[lo:hi] - td
            ring = sign * door * np.exp(-tau / m.door_decay_s) * np.sin(wd * tau)
            x[lo:hi] += ring
            z[lo:hi] += 0.5 * ring
    return x, z


__all__ = ["DOOR_RING_DECAYS", "Plan", "plan", "standstill_accel"]
