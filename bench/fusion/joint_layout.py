"""The joint filter's state and parameter layout: the slots of the float64 arrays the
compiled kernel (:mod:`bench.fusion.joint_kernel`) carries between calls, and the state
before the first sample.

x (NX): the state, slots I*; P: its covariance; m (M_SIZE): the kernel's bookkeeping, slots
M_*; p (P_SIZE): the parameters, slots P_*, filled by :mod:`bench.fusion.joint`. Plain ints,
so numba compiles them into the kernel as constants.

State x (see docs/ESTIMATOR.md):

====  ========================================================================
v     speed along the track, m/s, signed like SPEED_REF
a     acceleration dv/dt, m/s^2 (random walk in time)
s     g sin(alpha): gravity along the track, m/s^2 (random walk in distance)
k     ds/dx, the gradient's rate per metre (vertical curves; random walk in distance)
l     odometer latency beyond the clock alignment, s (constant unless enabled)
b     bias of w, the specific force normal to the track, m/s^2 (slow random walk)
z     the car body's vertical velocity, m/s (Gauss-Markov: its vibration, whose
      integral a suspension keeps bounded)
zc    z at the end of the previous w block (a clone: a block's mean of w holds
      (z - zc) / T of vibration)
====  ========================================================================
"""

from __future__ import annotations

import math

import numpy as np

NX = 8
IV, IA, IS, IK, IL, IB, IZ, IZC = 0, 1, 2, 3, 4, 5, 6, 7

# -- misc state slots (float64 array ``m``) ------------------------------------------------
M_STARTED = 0  # 1 after the first sample
M_LAST_B = 1  # board time of the previous sample, s
M_NOISE2 = 2  # channel noise variance estimate, (m/s^2)^2
M_NOISE_N = 3  # residuals averaged so far (for the first-second mean)
M_LAST_FRAME = 4  # board time of the newest SPEED_REF frame, s (-inf: none yet)
M_STILL = 5  # the newest frame said standstill
M_SUSPECT = 6  # odometer suspect
M_STREAK_T0 = 7  # board time of the first rejected frame of the current streak (NaN: none)
M_STREAK_NU0 = 8  # its innovation
M_OK_SINCE = 9  # board time of the first accepted frame since the last rejection (NaN)
M_ZUPT_FROM = 10  # zero-velocity updates blocked before this board time
M_HAVE_V = 11  # the speed has been initialised from an odometer frame
M_RV = 12  # innovation-based odometer noise variance estimate
M_LAST_SEEN = 13  # board time of the newest frame measured (applied or rejected)
M_RESLOW = 14  # slow mean of the parity residual, m/s^2
M_QUANT = 15  # least non-zero step between odometer readings, m/s (inf: none yet)
M_LAST_Z = 16  # the previous reading, m/s
M_HAVE_Z = 17  # 1 once there is a previous reading
M_WSUM = 18  # sum of w over the current block
M_WCOUNT = 19  # samples in it
M_WT0 = 20  # board time of its first sample
M_WVAR = 21  # learnt variance of a block mean's innovation (vibration), (m/s^2)^2
M_WFLOOR = 22  # sum of the white-noise variance factors of the block's samples
M_WE = 23  # moving mean of the block innovations (the curve detector)
M_WEVAR = 24  # its learnt variance while no curve shows
M_WHOLD = 25  # board time before which the detector does not fire again
M_UFAST = 26  # fast moving mean of u (motion at standstill)
M_USTILL = 27  # mean of u over the quiet part of the current standstill
M_USTILL_N = 28  # samples in it (0: no standstill going on)
M_STEP_T = 29  # board time of the latest acceleration step (u gate)
M_STEP_A0 = 30  # the acceleration before it
M_WE1 = 31  # the curve detector's first moving mean (M_WE is the second, of this)
M_NOTCH_X1 = 32  # the vibration notch's state (block innovations through its poles), n-1
M_NOTCH_X2 = 33  # ... n-2
M_NOTCH_TH = 34  # cos of its frequency per block (NaN: not started)
M_NOTCH_POW = 35  # moving power of its state, for the normalised step of TH
M_WPEND = 36  # s error a curve the detector is still judging may have caused, m/s^2
M_NOTCH_IN = 37  # moving power of the block innovations into the notch
M_NOTCH_OUT = 38  # ... and of what it leaves of them
M_ROUGH = 39  # 0..1: how much the body's vibration drowns w (block spread, see _predict)
M_HALF_T0 = 40  # board time the curve detector passed HALF_WAY (60 %) of its threshold (NaN: not)
M_JUMP_DK = 41  # k step the last block's gate applied (the next block may show more of it)
M_OUT_SINCE = 42  # board time the channel mask last left 7 (NaN: all three in)
M_BANK = 43  # 1 while the drift copies run (bench.fusion.joint_drift)
M_BANK_WT0 = 44  # board time of their current w block's first sample (NaN: none)
M_ZVAR = 45  # stationary variance of z, from the learnt block variance, (m/s)^2
M_ZCLONE_T = 46  # board time zc was cloned (NaN: no clone)
M_REWIND_FROM = 47  # board time of the oldest state the kernel can rewind to (inf: none)
M_REWIND_T = 48  # a curve the detector found began at this board time: rewind (NaN: no)
M_REWIND_DK = 49  # its k step, (m/s^2)/m
M_REWIND_AT = 50  # board time of the sample that fired (its replay resets the detector)
M_SNAP_T = 51  # board time of the newest state kept for rewinding
M_SIZE = 52

# per drift copy (bench.fusion.joint_drift), rows of its (3, MB_SIZE) array
MB_LL = 0  # log-likelihood of its odometer, standstill and w innovations since the start
MB_WSUM = 1  # sum of its w over the current block
MB_WCOUNT = 2  # samples in it
MB_WFLOOR = 3  # sum of the white-noise variance factors of its block's samples
MB_SIZE = 4

# -- parameters (float64 array ``p``) ------------------------------------------------------
P_QA = 0  # acceleration random walk, (m/s^2)^2/s
P_QS = 1  # gradient (s) random walk per metre, (m/s^2)^2/m
P_QK = 2  # grade-rate random walk per metre, ((m/s^2)/m)^2/m
P_QL = 3  # latency random walk, s^2/s
P_RV = 4  # least odometer noise variance (floor^2 + quantum^2/12), (m/s)^2
P_GATE = 5  # innovation gate, nu^2/S beyond this is rejected
P_RECOVER = 6  # s of accepted frames before "suspect" clears
P_RESET = 7  # s of rejected frames before the speed restarts at the odometer
P_SLIP = 8  # innovation slope (m/s^2) beyond which a rejected streak is slip/slide
P_COAST = 9  # s without SPEED_REF before "coasting"
P_RZ = 10  # zero-velocity update: acceleration variance, (m/s^2)^2
P_ZGATE = 11  # |u - s| beyond this (m/s^2) blocks the zero-velocity update
P_ZHOLD = 12  # s the zero-velocity update stays blocked after that
P_NOISE_FLOOR = 13  # channel noise variance floor, (m/s^2)^2
P_NOISE_TAU = 14  # s, time constant of the channel noise estimate
P_G = 15  # gravity, m/s^2
P_LIMIT = 16  # gradient withheld when its 1-sigma exceeds this, permil
P_S0 = 17  # initial 1-sigma of s, m/s^2
P_K0 = 18  # initial 1-sigma of k, (m/s^2)/m
P_A0 = 19  # initial 1-sigma of a, m/s^2
P_L0 = 20  # initial latency, s
P_LSIG = 21  # initial 1-sigma of the latency, s (0: not estimated)
P_RV_MAX = 22  # cap of the innovation-based odometer noise variance
P_RV_TAU = 23  # frames, time constant of that estimate
P_RV0 = 24  # odometer noise variance assumed at the start, (m/s)^2
P_RESLOW_TAU = 25  # s, time constant of the residual's slow mean
P_KJUMP = 26  # 1-sigma added to k when a clean odometer drift shows a curve missed, (m/s^2)/m
P_UGATE = 27  # u innovation beyond this (nu^2/S): the acceleration stepped
P_QK_BLIND = 28  # k's random walk per metre while no odometer frame is accepted
P_RES_LIMIT = 29  # residual limit, m/s^2 (clip of the residual's statistics)
P_LAT_ACC = 30  # m/s^2: the latency is estimated only while |a| exceeds this
P_WBLOCK = 31  # s, w is averaged over blocks this long
P_QB = 32  # w bias random walk, (m/s^2)^2/s
P_B0 = 33  # initial 1-sigma of the w bias, m/s^2
P_WGATE = 34  # block innovation beyond this (nu^2/S) is not applied
P_WVAR_TAU = 35  # blocks, time constant of the learnt block variance
P_USE_W = 36  # 1: apply the w blocks (0: the filter ignores w)
P_KMAX = 37  # largest |k| a line has (its sharpest vertical curve), (m/s^2)/m
P_WDET_TAU = 38  # s, time constant of the curve detector's moving mean
P_WDET_SIGMA = 39  # it fires beyond this many of its sigmas
P_WDET_MIN = 40  # and beyond this many m/s^2
P_WDET_VAR_TAU = 41  # s, time constant of its learnt variance
P_WCORR = 42  # s, correlation time of the body's vertical vibration (inflates R per block)
P_UFAST_TAU = 43  # s, time constant of u's fast moving mean
P_USTILL_TAU = 44  # s, longest memory of the standstill's mean of u
P_WRES_MAX = 45  # m/s^2: w is not used while |the residual's slow mean| exceeds this
P_BIAS = 46  # 1-sigma of the sensors' bias after calibration (drift), along the track
P_NOTCH_RHO = 47  # pole radius of the adaptive notch on the block innovations (0: none)
P_NOTCH_MU = 48  # its normalised adaptation step
P_QK_ROUGH = 49  # k's random walk per metre on a rough ride
P_WROUGH = 50  # m/s^2: block spread of w at which a ride counts as rough
P_DRIFT_LLR = 51  # a drift copy is trusted once it leads the others by this log-likelihood
P_ZTAU = 52  # s, correlation time of the body's vertical velocity (0: no z states)
P_ZMIS = 53  # share of the learnt block variance the z model leaves in R
P_REWIND = 54  # s: how far back a curve's start may be replayed from (0: never)
P_KVIS = 55  # m/s: below this the detector misses curves, and k walks faster (0: never)
P_SIZE = 56

# -- rewinding (bench.fusion.joint_rewind): the recent inputs and states the kernel keeps --
HIST_N = 8192  # samples kept (8.2 s at 1 kHz)
H_B, H_U, H_W, H_MASK, H_RES, H_LATCHED, H_F0, H_FN = 0, 1, 2, 3, 4, 5, 6, 7
H_SIZE = 8  # per sample: its inputs and where its SPEED_REF frames are in the frame ring
FRING_N = 1024  # SPEED_REF frames kept (20 s at 50 Hz)
F_WHEN, F_SPEED, F_RESTART, F_STILL = 0, 1, 2, 3
F_SIZE = 4
SNAP_N = 40  # states kept, one per SNAP_EVERY_S: 2 s
SNAP_EVERY_S = 0.05
C_SEQ, C_SNAPS, C_FRAMES = 0, 1, 2  # counters (int64): samples, states and frames kept so far
C_REWINDS = 3  # rewinds done
C_REWOUND_TO = 4  # the sample count of the state the latest rewind went back to
C_FLOOR = 5  # the first kept state (counted) a rewind may go back to: its replay's first
C_SIZE = 6
S_T, S_SEQ = 0, 1  # a kept state: board time and sample count after it, then x, P, m, copies
S_X = 2
S_COV = S_X + NX
S_M = S_COV + NX * NX
S_BX = S_M + M_SIZE
S_BCOV = S_BX + 3 * NX
S_BM = S_BCOV + 3 * NX * NX
SNAP_SIZE = S_BM + 3 * MB_SIZE


def new_state(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, P, m) before the first sample."""
    x = np.zeros(NX)
    x[IL] = p[P_L0]
    cov = np.zeros((NX, NX))
    cov[IV, IV] = 100.0  # speed unknown until an odometer frame or a standstill says it
    cov[IA, IA] = p[P_A0] ** 2
    cov[IS, IS] = p[P_S0] ** 2
    cov[IK, IK] = p[P_K0] ** 2
    cov[IL, IL] = p[P_LSIG] ** 2
    cov[IB, IB] = p[P_B0] ** 2
    m = np.zeros(M_SIZE)
    m[M_LAST_FRAME] = -math.inf
    m[M_LAST_SEEN] = -math.inf
    m[M_STREAK_T0] = math.nan
    m[M_OK_SINCE] = math.nan
    m[M_ZUPT_FROM] = -math.inf
    m[M_RV] = p[P_RV0]
    m[M_QUANT] = math.inf
    m[M_WT0] = math.nan
    m[M_HALF_T0] = math.nan
    m[M_OUT_SINCE] = math.nan
    m[M_BANK_WT0] = math.nan
    m[M_ZCLONE_T] = math.nan
    m[M_REWIND_FROM] = math.inf
    m[M_REWIND_T] = math.nan
    m[M_REWIND_AT] = math.nan
    m[M_SNAP_T] = -math.inf
    m[M_WVAR] = 0.0
    m[M_STEP_T] = -math.inf
    return x, cov, m
