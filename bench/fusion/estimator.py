"""The bench's own estimator (METHOD.md section 5) — minimal least-squares form.

Placeholder interface kept by the pipeline; the full estimator (a_ref, isolation) extends it.
"""

from __future__ import annotations

import numpy as np

from bench.config import Config
from bench.events import EVENT_DTYPE

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
    ]
)


class Estimator:
    def __init__(self, config: Config) -> None:
        self.config = config

    def push(
        self, samples: np.ndarray, acc: np.ndarray, usable: np.ndarray, speeds: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        out = np.zeros(len(samples), dtype=ESTIMATE_DTYPE)
        for name in ("gradient_signed", "gradient_ls", "u", "w", "a_ref", "residual"):
            out[name] = np.nan
        return out, np.zeros(0, dtype=EVENT_DTYPE)
