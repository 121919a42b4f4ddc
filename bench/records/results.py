"""The result of fusion per sampling instant: one numpy row layout (columns: records.columns)."""

from __future__ import annotations

import numpy as np

RESULT_DTYPE = np.dtype(
    [
        ("n", "<i8"),  # unwrapped sample index
        ("seq", "<i8"),  # arrival index of the sample's last frame
        ("ticks", "<i8"),  # unwrapped board time, 100 us ticks
        ("t", "<f8"),  # receive time of the sample's last frame, s
        ("time_s", "<f8"),  # board time from the first sample, s
        ("code", "<i4", (3,)),
        ("status", "u1", (3,)),
        ("present", "?", (3,)),
        ("acc", "<f8", (3,)),  # calibrated m/s^2; NaN where the channel is not usable
        ("slopes", "<f8", (3,)),  # g12, g23, g13 per mille (reference method)
        ("votes", "?", (3,)),  # v1, v2, v3
        ("weights", "<f8", (3,)),  # w12, w23, w13
        ("gradient", "<f8"),  # reference result per mille; NaN when invalid
        ("valid", "?"),
        # the bench's own estimator (METHOD.md section 5)
        ("gradient_signed", "<f8"),  # joint filter, per mille; NaN when withheld
        ("gradient_ls", "<f8"),  # least-squares magnitude per mille (no a_ref needed)
        ("u", "<f8"),  # specific force along the track, m/s^2
        ("w", "<f8"),  # specific force normal to the track, m/s^2
        ("a_ref", "<f8"),  # reference acceleration from SPEED_REF, m/s^2; NaN when unavailable
        ("residual", "<f8"),  # least-squares residual, m/s^2
        ("degraded", "?"),  # computed from two channels only
        ("excluded", "u1"),  # channel excluded by the estimator (1..3), 0 = none
        ("gradient_sigma", "<f8"),  # 1-sigma of the estimator's gradient, per mille
        ("odometer_suspect", "?"),  # SPEED_REF rejected by the innovation gate (slip/slide)
        ("coasting", "?"),  # no SPEED_REF for coast_s: the filter runs on the accelerometers
    ]
)

ESTIMATE_DTYPE = np.dtype(
    [
        ("gradient_signed", "<f8"),
        ("gradient_ls", "<f8"),
        ("u", "<f8"),
        ("w", "<f8"),
        ("a_ref", "<f8"),
        ("residual", "<f8"),
        ("degraded", "?"),
        ("excluded", "u1"),
        ("gradient_sigma", "<f8"),
        ("odometer_suspect", "?"),
        ("coasting", "?"),
    ]
)
"""The estimator's row (bench.fusion.estimator): the last fields of RESULT_DTYPE, kept here
so the pipeline knows the layout without importing the estimator (and numba)."""

SMOOTHED_DTYPE = np.dtype(
    [
        *RESULT_DTYPE.descr,
        ("gradient_smoothed", "<f8"),  # the model's RTS smoother, per mille; NaN when withheld
        ("gradient_smoothed_sigma", "<f8"),  # its 1-sigma, per mille
    ]
)
"""The results with the smoother's columns (`bench replay --smooth`)."""

UNIX_TIME_FROM = 946_684_800.0
"""Receive times ``t`` at or after 2000-01-01T00:00:00Z are Unix time (a wall clock stamped
the frame); smaller ones are relative to the start of a recording (an emulator's run time)."""

VOTE_SLOPES = ((0, 1), (1, 2), (0, 2))
"""The two ``slopes`` columns each of ``votes`` v1, v2, v3 compares (g12~g23, g23~g13,
g12~g13): how a screen labels a vote without importing fusion (bench.fusion.reference)."""
