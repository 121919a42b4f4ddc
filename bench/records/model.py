"""The explicit model's live estimates, one row per block (issue 26: `--lag`): the layout
the live MCAP log's ``/bench/model`` topic and the TUI's model panel share."""

from __future__ import annotations

import numpy as np

MODEL_DTYPE = np.dtype(
    [
        ("block", "<i8"),  # the model's step since the run's start (blocks of BLOCK_S)
        ("t", "<f8"),  # receive time of the block's last sample, s (the message's log time)
        ("board_t", "<f8"),  # the block's mid-time, board clock s (the results' ticks * 1e-4)
        ("gradient", "<f8"),  # the model's filter, per mille
        ("gradient_sigma", "<f8"),  # its 1-sigma, per mille
        ("gradient_lagged", "<f8"),  # fixed-lag smoothed: given lag_s of samples after it
        ("gradient_lagged_sigma", "<f8"),  # its 1-sigma, per mille
        ("lag_s", "<f8"),  # the lag, s
        ("wheel_error", "<f8"),  # E: the odometer reads (1 + E) v (wheel diameter error), 1
        ("wheel_error_sigma", "<f8"),
        ("compliance", "<f8"),  # C: the body's settled pitch per m/s^2, deg per m/s^2
        ("compliance_sigma", "<f8"),
        ("bias", "<f8", (3,)),  # B1-B3: each channel's bias left after calibration, m/s^2
        ("bias_sigma", "<f8", (3,)),
    ]
)
"""E, C and the biases as the filter has them at the block; the lagged gradient with lag_s
of samples after the block (so a row is written lag_s after its block)."""

NO_MODEL_ROWS = np.zeros(0, dtype=MODEL_DTYPE)
