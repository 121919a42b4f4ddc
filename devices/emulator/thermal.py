"""The board's and each channel's temperature (issue 25): the enclosure warms while the
train runs and cools at stations, and every sensor lags the board by its own thermal time
constant, so the channels' biases drift apart (``bias_tempco_mps2_per_k`` of each channel
acts on its own temperature).

* Board: first order, ``dT_b/dt = (u(t) - T_b) / tau_b``, ``T_b(0) = temperature_c``,
  ``tau_b = temperature_tau_s``. The target u is ``temperature_end_c`` (``temperature_c``
  without it) while the train runs and ``station_cooling_k`` below that while it stands at a
  station (the stops of :func:`devices.emulator.body_pitch.scenario_stations`): doors open,
  no traction heat. u is piecewise constant, so T_b is exact: a sum of step responses.
* Channel i: first order behind the board, ``dT_i/dt = (T_b - T_i) / tau_i``,
  ``T_i(0) = T_b(0)``, ``tau_i = thermal_lag_s`` (0: at the board's temperature). The
  response of the two lags in series to a unit step of u is
  ``1 - (tau_b e^(-s/tau_b) - tau_i e^(-s/tau_i)) / (tau_b - tau_i)``
  (``1 - (1 + s/tau) e^(-s/tau)`` for equal constants).

With ``station_cooling_k = 0`` and every ``thermal_lag_s = 0`` this is the board's
exponential approach of before, exactly.
"""

from __future__ import annotations

import numpy as np

from devices.emulator.scenario import Scenario

EQUAL_TAU = 1e-6
"""Relative difference of two time constants below which the equal-constant form is used."""


class Thermal:
    """Board and channel temperatures (deg C) of one scenario at any run times."""

    def __init__(self, sc: Scenario, stations: list[tuple[float, float]]) -> None:
        b = sc.board
        self.t0 = float(b.temperature_c)
        self.tau_b = b.temperature_tau_s
        self.lags = tuple(c.thermal_lag_s for c in sc.channels)
        self.running = self.t0 if b.temperature_end_c is None else float(b.temperature_end_c)
        times: list[float] = []
        steps: list[float] = []
        cool = b.station_cooling_k
        if cool:
            for start, end in stations:
                times.append(start)
                steps.append(-cool)
                if end < sc.duration_s:
                    times.append(end)
                    steps.append(cool)
        self.times = np.array(times, dtype=np.float64)
        self.steps = np.array(steps, dtype=np.float64)

    def board(self, t: np.ndarray) -> np.ndarray:
        """The board's (the enclosure's) temperature: what BOARD_STATUS reports."""
        return self._response(np.asarray(t, dtype=np.float64), 0.0)

    def channel(self, i: int, t: np.ndarray) -> np.ndarray:
        """Channel i's (0-based) own temperature."""
        return self._response(np.asarray(t, dtype=np.float64), self.lags[i])

    def _response(self, t: np.ndarray, lag: float) -> np.ndarray:
        t0, run, tau = self.t0, self.running, self.tau_b
        since = np.maximum(t, 0.0)
        if lag == 0.0:  # the board's approach, as the emulator has always computed it
            out: np.ndarray = run + (t0 - run) * np.exp(-since / tau)
        else:
            out = t0 + (run - t0) * step_response(since, tau, lag)
        for t_k, step in zip(self.times, self.steps, strict=True):
            s = t - t_k
            after = s > 0.0
            out[after] += step * step_response(s[after], tau, lag)
        return out


def step_response(s: np.ndarray, tau_b: float, tau_c: float) -> np.ndarray:
    """Unit step response of 1/(1 + s tau_b) then 1/(1 + s tau_c) at times s >= 0."""
    s = np.asarray(s, dtype=np.float64)
    if tau_c == 0.0:
        out: np.ndarray = 1.0 - np.exp(-s / tau_b)
        return out
    if abs(tau_b - tau_c) <= EQUAL_TAU * max(tau_b, tau_c):
        tau = 0.5 * (tau_b + tau_c)
        out = 1.0 - (1.0 + s / tau) * np.exp(-s / tau)
        return out
    out = 1.0 - (tau_b * np.exp(-s / tau_b) - tau_c * np.exp(-s / tau_c)) / (tau_b - tau_c)
    return out


__all__ = ["EQUAL_TAU", "Thermal", "step_response"]
