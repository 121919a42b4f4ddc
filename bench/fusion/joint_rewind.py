"""Rewinding the joint filter to a vertical curve's start, once the curve detector has found it.

On a rough ride the detector needs a few tenths of a second to tell a curve's v^2/R from
the body's vibration; by then the curve has been moving s by its k all that while, and
the filter, not yet told, has put what it saw into the acceleration, z and the bias. Rather
than patch the present state (a guessed share of s's error, :data:`joint_w.AGE_REL`), the
kernel keeps the recent inputs and a state every :data:`~joint_layout.SNAP_EVERY_S`, and at
the detection goes back to the state kept just before the curve began, raises k's variance
there by the step the detector measured, and replays every sample since: the filter then
reads those samples as it would have, had it known. What it emits for the samples already
passed stays as emitted (they have left); only the present and what follows are corrected.

Every sample is recorded first and then filtered from the record, live and in replay alike,
so a replay runs the very arithmetic of the first pass and the state is carried in the
filter's arrays (:class:`bench.fusion.joint.JointFilter`): batch and streaming stay
identical. Compiled by numba; called from :func:`bench.fusion.joint_kernel.run`.
"""

from __future__ import annotations

import math

from numba import njit

from bench.fusion.joint_layout import (
    C_FLOOR,
    C_FRAMES,
    C_REWINDS,
    C_REWOUND_TO,
    C_SEQ,
    C_SNAPS,
    F_RESTART,
    F_SPEED,
    F_STILL,
    F_WHEN,
    FRING_N,
    H_B,
    H_F0,
    H_FN,
    H_LATCHED,
    H_MASK,
    H_RES,
    H_U,
    H_W,
    HIST_N,
    IK,
    M_REWIND_AT,
    M_REWIND_DK,
    M_REWIND_FROM,
    M_REWIND_T,
    M_SIZE,
    M_SNAP_T,
    M_WHOLD,
    MB_SIZE,
    NX,
    P_REWIND,
    S_BCOV,
    S_BM,
    S_BX,
    S_COV,
    S_M,
    S_SEQ,
    S_T,
    S_X,
    SNAP_N,
)


@njit(cache=True, inline="always")
def record(hist, ctr, bi, ui, wi, mask_i, res_i, latched_i):  # type: ignore[no-untyped-def]
    """A new sample into the input ring; returns its row."""
    slot = ctr[C_SEQ] % HIST_N
    ctr[C_SEQ] += 1
    hist[slot, H_B] = bi
    hist[slot, H_U] = ui
    hist[slot, H_W] = wi
    hist[slot, H_MASK] = mask_i
    hist[slot, H_RES] = res_i
    hist[slot, H_LATCHED] = latched_i
    hist[slot, H_F0] = ctr[C_FRAMES]  # frames are counted, not wrapped: a replay checks reach
    hist[slot, H_FN] = 0.0
    return slot


@njit(cache=True, inline="always")
def add_frame(hist, fring, ctr, slot, when, speed, restart, still):  # type: ignore[no-untyped-def]
    """A SPEED_REF frame the sample in ``slot`` applies, into the frame ring."""
    q = ctr[C_FRAMES] % FRING_N
    ctr[C_FRAMES] += 1
    fring[q, F_WHEN] = when
    fring[q, F_SPEED] = speed
    fring[q, F_RESTART] = 1.0 if restart else 0.0
    fring[q, F_STILL] = 1.0 if still else 0.0
    hist[slot, H_FN] += 1.0


@njit(cache=True)
def reach(snaps, hist, ctr, p):  # type: ignore[no-untyped-def]
    """Board time of the oldest kept state a replay can start from (inf: none): its samples
    and their frames must all still be in the rings."""
    if p[P_REWIND] <= 0.0:
        return math.inf
    kept = ctr[C_SNAPS] if ctr[C_SNAPS] < SNAP_N else SNAP_N
    # from the oldest: a newer state is usable whenever an older one is, so this is
    # usually the first
    for back in range(kept - 1, -1, -1):
        if ctr[C_SNAPS] - 1 - back < ctr[C_FLOOR]:
            continue  # before the last rewind's replay (restore)
        row = (ctr[C_SNAPS] - 1 - back) % SNAP_N
        seq = int(snaps[row, S_SEQ])
        if seq < ctr[C_SEQ] - HIST_N:
            continue
        if seq < ctr[C_SEQ] and hist[seq % HIST_N, H_F0] < ctr[C_FRAMES] - FRING_N:
            continue
        return snaps[row, S_T]
    return math.inf


@njit(cache=True)
def keep(snaps, hist, ctr, p, x, cov, m, xb, cb, mb, q):  # type: ignore[no-untyped-def]
    """Keep the state after sample number q (the caller keeps one per SNAP_EVERY_S), and
    note in m how far back a rewind can now go (M_REWIND_FROM, for the curve detector)."""
    bi = hist[q % HIST_N, H_B]
    seq = q + 1
    m[M_SNAP_T] = bi
    row = ctr[C_SNAPS] % SNAP_N
    ctr[C_SNAPS] += 1
    snaps[row, S_T] = bi
    snaps[row, S_SEQ] = seq
    for i in range(NX):
        snaps[row, S_X + i] = x[i]
        for j in range(NX):
            snaps[row, S_COV + i * NX + j] = cov[i, j]
    for i in range(M_SIZE):
        snaps[row, S_M + i] = m[i]
    for c in range(3):
        for i in range(NX):
            snaps[row, S_BX + c * NX + i] = xb[c, i]
            for j in range(NX):
                snaps[row, S_BCOV + (c * NX + i) * NX + j] = cb[c, i, j]
        for i in range(MB_SIZE):
            snaps[row, S_BM + c * MB_SIZE + i] = mb[c, i]
    m[M_REWIND_FROM] = reach(snaps, hist, ctr, p)


@njit(cache=True)
def restore(snaps, ctr, m, x, cov, xb, cb, mb):  # type: ignore[no-untyped-def]
    """Back to the newest kept state before the curve's start (m[M_REWIND_T]), with k's
    variance raised by its step; returns that state's row. The detector's hold and the
    firing sample's time survive (the replay must not fire again, and resets the detector
    at that sample); later kept states are dropped, the replay keeps its own."""
    t_on = m[M_REWIND_T]
    hold, at, dk = m[M_WHOLD], m[M_REWIND_AT], m[M_REWIND_DK]
    kept = ctr[C_SNAPS] if ctr[C_SNAPS] < SNAP_N else SNAP_N
    back = 0
    # never past the first state a previous rewind's replay kept: older ones do not know
    # of that curve (the replay would drop what the last rewind told it)
    while (
        back < kept - 1
        and ctr[C_SNAPS] - 2 - back >= ctr[C_FLOOR]
        and snaps[(ctr[C_SNAPS] - 1 - back) % SNAP_N, S_T] >= t_on
    ):
        back += 1
    row = (ctr[C_SNAPS] - 1 - back) % SNAP_N
    ctr[C_SNAPS] -= back
    ctr[C_FLOOR] = ctr[C_SNAPS]
    for i in range(NX):
        x[i] = snaps[row, S_X + i]
        for j in range(NX):
            cov[i, j] = snaps[row, S_COV + i * NX + j]
    for i in range(M_SIZE):
        m[i] = snaps[row, S_M + i]
    for c in range(3):
        for i in range(NX):
            xb[c, i] = snaps[row, S_BX + c * NX + i]
            for j in range(NX):
                cb[c, i, j] = snaps[row, S_BCOV + (c * NX + i) * NX + j]
        for i in range(MB_SIZE):
            mb[c, i] = snaps[row, S_BM + c * MB_SIZE + i]
    cov[IK, IK] += dk * dk
    ctr[C_REWINDS] += 1
    ctr[C_REWOUND_TO] = int(snaps[row, S_SEQ])
    m[M_REWIND_DK] = dk
    m[M_WHOLD] = hold
    m[M_REWIND_AT] = at
    m[M_REWIND_T] = math.nan
    return row
