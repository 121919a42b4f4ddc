"""The joint filter (speed, acceleration, gradient): settings, state and one call per push.

The arithmetic is in :mod:`bench.fusion.joint_kernel`, compiled once; this module holds the
state between pushes and turns settings into the kernel's parameter vector. Every push,
whatever its length, goes through the same compiled loop, which is what keeps live and
replay identical to the bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.config import Config
from bench.fusion import joint_kernel as jk
from bench.fusion import joint_layout as jl
from bench.fusion.least_squares import Geometry

_EMPTY_F = np.zeros(0)
_EMPTY_I = np.zeros(0, dtype=np.int64)
_EMPTY_B = np.zeros(0, dtype=np.bool_)
_EMPTY_I8 = np.zeros(0, dtype=np.int8)


def parameters(config: Config) -> np.ndarray:
    """The kernel's parameter vector from a config."""
    s = config.estimator
    p = np.zeros(jl.P_SIZE)
    p[jl.P_QA] = s.accel_psd
    p[jl.P_QS] = s.grade_psd_per_m
    p[jl.P_QK] = s.grade_rate_psd_per_m
    p[jl.P_QK_ROUGH] = s.grade_rate_psd_rough_per_m
    p[jl.P_WROUGH] = s.rough_ride_mps2
    p[jl.P_QL] = s.latency_psd
    p[jl.P_RV] = s.odometer_noise_floor_mps**2 + s.speed_quantum_mps**2 / 12.0
    p[jl.P_RV0] = s.speed_noise_mps**2 + s.speed_quantum_mps**2 / 12.0
    p[jl.P_GATE] = s.odometer_gate_sigma**2
    p[jl.P_RECOVER] = s.suspect_recover_s
    p[jl.P_RESET] = s.odometer_reset_s
    p[jl.P_SLIP] = s.slip_accel_mps2
    p[jl.P_COAST] = s.coast_s
    p[jl.P_RZ] = s.zupt_accel_sigma_mps2**2
    p[jl.P_ZGATE] = s.zupt_gate_mps2
    p[jl.P_ZHOLD] = s.standstill_s
    p[jl.P_NOISE_FLOOR] = s.channel_noise_floor_mps2**2
    p[jl.P_NOISE_TAU] = s.channel_noise_tau_s
    p[jl.P_G] = config.g
    p[jl.P_LIMIT] = config.gradient_sigma_limit_permil
    p[jl.P_S0] = s.grade_sigma0_mps2
    p[jl.P_K0] = s.grade_rate_sigma0
    p[jl.P_A0] = 1.0
    p[jl.P_L0] = s.odometer_latency_s
    p[jl.P_LSIG] = s.latency_sigma_s
    p[jl.P_RV_MAX] = s.speed_noise_max_mps**2
    p[jl.P_RV_TAU] = 200.0
    p[jl.P_RESLOW_TAU] = 1.0
    p[jl.P_RES_LIMIT] = s.residual_limit_mps2
    p[jl.P_LAT_ACC] = s.latency_min_accel_mps2
    p[jl.P_KJUMP] = s.grade_rate_jump
    p[jl.P_UGATE] = 25.0
    p[jl.P_QK_BLIND] = s.blind_grade_rate_psd_per_m
    p[jl.P_WBLOCK] = s.w_block_s
    p[jl.P_QB] = s.w_bias_psd
    p[jl.P_B0] = s.w_bias_sigma0_mps2
    p[jl.P_WGATE] = 25.0
    p[jl.P_WVAR_TAU] = 20.0
    p[jl.P_USE_W] = 1.0 if s.w_block_s > 0.0 else 0.0
    p[jl.P_KMAX] = config.g / s.vertical_radius_min_m
    p[jl.P_WDET_TAU] = s.curve_detect_s
    p[jl.P_WDET_SIGMA] = s.curve_detect_sigma
    p[jl.P_WDET_MIN] = s.curve_detect_min_mps2
    p[jl.P_WDET_VAR_TAU] = 5.0
    p[jl.P_WCORR] = s.vibration_corr_s
    p[jl.P_UFAST_TAU] = 0.05
    p[jl.P_USTILL_TAU] = 2.0
    p[jl.P_WRES_MAX] = 0.1 * s.residual_limit_mps2
    p[jl.P_BIAS] = s.bias_sigma_mps2
    p[jl.P_ZTAU] = s.body_velocity_tau_s
    p[jl.P_ZMIS] = s.body_velocity_mismatch
    p[jl.P_REWIND] = s.curve_rewind_s
    p[jl.P_KVIS] = s.curve_visible_speed_mps
    p[jl.P_NOTCH_RHO] = s.vibration_notch_radius
    p[jl.P_NOTCH_MU] = 0.01
    p[jl.P_DRIFT_LLR] = s.drift_llr
    return p


def u_variance_factors(geo: Geometry, row_index: int = 0) -> np.ndarray:
    """(H^T H)^-1 uu per channel-mask code: the variance of u per unit channel noise
    variance (sum of the squared u-row of the pseudo-inverse); inf below two channels.
    ``row_index`` 1: the same for w."""
    out = np.full(8, math.inf)
    for code in range(8):
        row = geo.pinv_array[code, row_index]
        if np.isfinite(row).all():
            out[code] = float(np.dot(row, row))
    return out


def exclusion_gains(geo: Geometry, row_index: int = 0) -> np.ndarray:
    """Per channel k, u's weight over the parity's (three channels): an error e on k moves
    the residual by e p_k and u by e c_k, so a residual r means c_k / p_k r in u.
    ``row_index`` 1: the same for w."""
    cu = geo.pinv_array[7, row_index]
    par = np.asarray(geo.parity)
    return np.where(np.abs(par) > 0.05, cu / np.where(par == 0, 1.0, par), 0.0)


@dataclass(slots=True)
class FilterOutput:
    gradient: np.ndarray  # permil, NaN where withheld
    sigma: np.ndarray  # 1-sigma, permil
    suspect: np.ndarray  # odometer suspect
    coasting: np.ndarray  # no SPEED_REF for coast_s
    accel: np.ndarray  # the filter's acceleration, m/s^2


class JointFilter:
    """Stateful; :meth:`push` every batch of samples in order, with the frames they apply."""

    def __init__(self, config: Config, geo: Geometry) -> None:
        self.p = parameters(config)
        self.x, self.cov, self.m = jl.new_state(self.p)
        self.ru = u_variance_factors(geo)
        self.rw = u_variance_factors(geo, 1)
        self.excl_gain = exclusion_gains(geo)
        self.excl_gain_w = exclusion_gains(geo, 1)
        # the drift copies (joint_drift): state, covariance, bookkeeping per channel left out
        self.bank_x = np.zeros((3, jl.NX))
        self.bank_cov = np.zeros((3, jl.NX, jl.NX))
        self.bank_m = np.zeros((3, jl.MB_SIZE))
        # what the kernel keeps to rewind to a curve's start (joint_rewind)
        self.hist = np.zeros((jl.HIST_N, jl.H_SIZE))
        self.fring = np.zeros((jl.FRING_N, jl.F_SIZE))
        self.snaps = np.zeros((jl.SNAP_N, jl.SNAP_SIZE))
        self.ctr = np.zeros(jl.C_SIZE, dtype=np.int64)
        # compile or load the kernel now, when the pipeline is built (before acquisition),
        # not on the first live sample; an empty batch leaves the state as it is
        self.push(_EMPTY_F, _EMPTY_F, _EMPTY_F, _EMPTY_I, _EMPTY_F, _EMPTY_I8, None)

    @property
    def rewinds(self) -> int:
        """How often the filter went back to a vertical curve's start (joint_rewind)."""
        return int(self.ctr[jl.C_REWINDS])

    def push(
        self,
        b: np.ndarray,
        u: np.ndarray,
        w: np.ndarray,
        mask: np.ndarray,
        residual: np.ndarray,
        latched: np.ndarray,
        frames: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None,
    ) -> FilterOutput:
        """b board time (s), u, w, channel-mask code, parity residual and the channel (1..3)
        whose exclusion starts, per sample; frames:
        (anchor index, board time measured, speed m/s, restart, standstill) or None."""
        n = len(b)
        out = FilterOutput(
            np.empty(n), np.empty(n), np.empty(n, np.bool_), np.empty(n, np.bool_), np.empty(n)
        )
        fa, fw, fs, fr, fst = (
            frames if frames is not None else (_EMPTY_I, _EMPTY_F, _EMPTY_F, _EMPTY_B, _EMPTY_B)
        )
        jk.run(
            self.x, self.cov, self.m, self.p,
            np.ascontiguousarray(b, dtype=np.float64),
            np.ascontiguousarray(u, dtype=np.float64),
            np.ascontiguousarray(w, dtype=np.float64),
            np.ascontiguousarray(mask, dtype=np.int64),
            np.ascontiguousarray(residual, dtype=np.float64),
            np.ascontiguousarray(latched, dtype=np.int8),
            self.ru,
            self.rw,
            self.excl_gain,
            self.excl_gain_w,
            self.bank_x,
            self.bank_cov,
            self.bank_m,
            self.hist,
            self.fring,
            self.snaps,
            self.ctr,
            np.ascontiguousarray(fa, dtype=np.int64),
            np.ascontiguousarray(fw, dtype=np.float64),
            np.ascontiguousarray(fs, dtype=np.float64),
            np.ascontiguousarray(fr, dtype=np.bool_),
            np.ascontiguousarray(fst, dtype=np.bool_),
            out.gradient, out.sigma, out.suspect, out.coasting, out.accel,
        )  # fmt: skip
        return out


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel before acquisition starts."""
    cfg = Config()
    from bench.fusion.least_squares import geometry

    f = JointFilter(cfg, geometry(cfg.angles_rad))
    f.push(
        np.array([0.0, 0.005]),
        np.array([0.0, 0.0]),
        np.array([9.8, 9.8]),
        np.array([7, 7]),
        np.array([0.0, math.nan]),
        np.array([0, 0], dtype=np.int8),
        (
            np.array([1]),
            np.array([0.0]),
            np.array([0.0]),
            np.array([False]),
            np.array([False]),
        ),
    )
