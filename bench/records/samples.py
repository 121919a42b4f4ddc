"""Sample rows: one per sampling instant, the three channels' codes joined by the assembler.

Fusion, the MCAP log and the acceptance checks read these rows; the assembler
(:mod:`bench.pipeline.assembly`) writes them.
"""

from __future__ import annotations

import numpy as np

from protocol.layout import STATUS_FAULT_MASK, TICK_S

SAMPLE_DTYPE = np.dtype(
    [
        ("n", "<i8"),  # unwrapped sample index (counter)
        ("ticks", "<i8"),  # unwrapped board time, 100 us ticks
        ("t", "<f8"),  # receive time of the sample's last accepted frame
        ("seq", "<i8"),  # arrival index (whole stream) of the sample's last accepted frame
        ("code", "<i4", (3,)),  # raw ADC codes ch1..ch3 (0 where absent)
        ("status", "u1", (3,)),  # status bytes ch1..ch3
        ("present", "?", (3,)),  # a frame of that channel joined the sample
    ]
)

NO_SAMPLES = np.zeros(0, dtype=SAMPLE_DTYPE)
"""Shared empty result: a zero-length array has nothing to write, so sharing is safe."""

MAX_BRIDGE_TICKS = 3600 / TICK_S
"""Longest receive-time gap (1 h) trusted to count board-timestamp wraps across."""


def usable(samples: np.ndarray) -> np.ndarray:
    """(N, 3) bool: channel present and none of status bits 0..3 set."""
    ok: np.ndarray = samples["present"] & ((samples["status"] & STATUS_FAULT_MASK) == 0)
    return ok
