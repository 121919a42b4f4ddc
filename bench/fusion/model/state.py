"""The model's state and parameters as named fields (indices into float64 arrays, so the
compiled code takes plain arrays; every index has one name here and nowhere else).

State x, in SI units:

====  ==========================================================================
V     speed along the track, m/s, signed like SPEED_REF
A     acceleration dv/dt, m/s^2 (driven by white jerk)
S     g sin(alpha), gravity along the track, m/s^2 (gradient = 1000 S / sqrt(g^2 - S^2))
K     dS/dx, the gradient's change per metre (vertical curves), m/s^2 per m
E     the odometer's wheel-scale error: it reads (1 + E) v (wheel diameter error), 1
B1-3  each channel's bias, m/s^2 (random walk: a drifting channel is a large bias)
L     the odometer's latency beyond the clock mapping, s: it reads v(t - L)
P     the car body's static pitch on its suspension (the load), rad, nose up: every
      channel's axis turns by it; it changes only while the train stands
C     the body's pitch compliance, rad per m/s^2: under a steady acceleration a the body
      settles at C a nose up (traction acts below the body's centre of gravity)
TB    the body's pitch on its secondary suspension from the acceleration, rad, nose up:
      the suspension's second-order response (natural frequency, damping) to C a; every
      channel's axis turns by P + TB
TW    dTB/dt, rad/s
====  ==========================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

V, A, S, K, E, B1, B2, B3, L, P, C, TB, TW = range(13)
NX = 13
NAMES = (
    "v", "a", "s", "k", "e", "b1", "b2", "b3", "latency", "pitch",
    "compliance", "accel_pitch", "accel_pitch_rate",
)  # fmt: skip
BIASES = (B1, B2, B3)


@dataclass(frozen=True, slots=True)
class ModelParams:
    """The model's noise densities and priors, each a physical quantity."""

    g: float = 9.80665  # local gravity, m/s^2
    jerk_psd: float = 0.1  # white jerk driving A, (m/s^3)^2 / Hz
    grade_psd_per_m: float = 1e-9  # white noise on S per metre, (m/s^2)^2 / m
    grade_rate_psd_per_m: float = 1e-9  # random walk of K per metre, (m/s^2/m)^2 / m
    wheel_scale_psd_per_m: float = 1e-12  # random walk of E per metre (wheel wear), 1/m
    bias_psd: float = 1e-12  # random walk of each channel's bias, (m/s^2)^2 / s
    channel_noise_mps2: float = 0.01  # each channel's white noise per sample, m/s^2
    vibration_u_mps2: float = 0.0  # least vibration of the body along the track, m/s^2
    vibration_w_mps2: float = 0.0  # ... and normal to it, m/s^2
    odometer_noise_mps: float = 0.05  # SPEED_REF noise, m/s
    speed0_mps: float = 1.0  # prior sigma of V
    accel0_mps2: float = 1.0  # prior sigma of A
    grade0_mps2: float = 0.5  # prior sigma of S (about 50 permil)
    grade_rate0_per_m: float = 1e-4  # prior sigma of K
    wheel_scale0: float = 0.03  # prior sigma of E (a 3 % wheel-diameter error)
    bias0_mps2: float = 1e-3  # prior sigma of each bias (what calibration leaves)
    latency_psd: float = 1e-8  # random walk of the odometer's latency, s^2 / s
    latency_sigma0_s: float = 0.03  # its prior sigma (mean 0), s
    load_pitch_psd: float = 0.0  # random walk of the body's pitch while standing, rad^2 / s
    vibration_tau_s: float = 10.0  # the body's vibration is learnt over this long, s
    pitch_frequency_hz: float = 1.2  # the body's pitch mode on its secondary suspension, Hz
    pitch_damping: float = 0.25  # ... and its damping ratio (0 < zeta < 1), 1
    compliance0_rad_per_mps2: float = 1.75e-3  # prior sigma of C (0.1 deg per m/s^2), rad/(m/s^2)
    compliance_mean_rad_per_mps2: float = 0.0  # prior mean of C, rad per m/s^2
    # a vertical curve's start or end steps K by g / R (radius R); 0 = no jump test
    curve_rate_step_per_m: float = 1.5e-3  # prior sigma of K's step, m/s^2 per m (g / 6.5 km)
    curve_spacing_m: float = 300.0  # mean distance between K's steps along the line, m
    curve_window_s: float = 2.0  # a step's onset is looked for this far back, s
    curve_min_age_s: float = 1.0  # ... and at least this far (a body mode's period), s

    def array(self) -> np.ndarray:
        """The fields as a float64 array, in the order of the P_* indices below."""
        return np.array([getattr(self, f.name) for f in fields(self)], dtype=np.float64)


(
    P_G,
    P_QJ,
    P_QS,
    P_QK,
    P_QE,
    P_QB,
    P_RCH,
    P_RVU,
    P_RVW,
    P_RODO,
    P_V0,
    P_A0,
    P_S0,
    P_K0,
    P_E0,
    P_B0,
    P_QL,
    P_LSIG0,
    P_QP,
    P_VTAU,
    P_PF,
    P_PZ,
    P_C0,
    P_CM,
    P_KJ,
    P_KSP,
    P_KWIN,
    P_KMIN,
) = range(28)
NP = 28


def initial(
    prm: ModelParams, speed: float = 0.0, grade_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Prior state and covariance: the given speed and S, C its prior mean, the rest zero."""
    x = np.zeros(NX)
    x[V] = speed
    x[S] = grade_s
    x[C] = prm.compliance_mean_rad_per_mps2
    sig = np.zeros(NX)
    sig[V], sig[A], sig[S] = prm.speed0_mps, prm.accel0_mps2, prm.grade0_mps2
    sig[K], sig[E] = prm.grade_rate0_per_m, prm.wheel_scale0
    for b in BIASES:
        sig[b] = prm.bias0_mps2
    sig[L] = prm.latency_sigma0_s
    sig[P] = prm.bias0_mps2 / prm.g  # calibration finds the board's angle as well as a bias
    sig[C] = prm.compliance0_rad_per_mps2
    # the body may be pitched by an acceleration the run starts in (at rest: by none)
    sig[TB] = prm.compliance0_rad_per_mps2 * prm.accel0_mps2
    sig[TW] = 2.0 * math.pi * prm.pitch_frequency_hz * sig[TB]
    return x, np.diag(sig * sig)
