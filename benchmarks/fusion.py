"""Fusion throughput in samples/s.

* ``fusion core``: the device's reference method alone (:func:`bench.fusion.reference.fuse`:
  pair gradients, two-out-of-three vote, weights) over (N, 3) accelerations, called on
  batches of the size replay feeds it (65536 frames -> 21845 samples).
* ``fusion + estimator``: :meth:`bench.pipeline.steps.Pipeline.compute` -- the reference method,
  the bench's estimator and the result rows, i.e. all the pipeline does after assembly.
"""

from __future__ import annotations

import numpy as np

from benchmarks.common import Figure, simulation, timed

FUSION_TARGET = 5e6
BATCH_SAMPLES = 65536 // 3


def _steps(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(samples, SPEED_REF records) per replay step for ``n`` samples of the 1 kHz board,
    through the real decoder and assembler."""
    from bench.config import Config
    from bench.pipeline.steps import Pipeline
    from devices.base import SourceBatch

    frames = simulation(n / 1000.0 + 1.0).frames
    p = Pipeline(Config())
    steps = [p.process(SourceBatch(frames[i : i + 65536])) for i in range(0, len(frames), 65536)]
    steps.append(p.finish())
    out, total = [], 0
    for s in steps:
        if total >= n:
            break
        out.append((s.samples[: n - total], s.speed))
        total += len(out[-1][0])
    return out


def measure(n_samples: int = 1_000_000, repeat: int = 5) -> list[Figure]:
    from bench.config import Config
    from bench.fusion.reference import fuse
    from bench.pipeline.steps import Pipeline
    from bench.records.samples import usable

    config = Config()
    steps = _steps(n_samples)
    samples = np.concatenate([s for s, _ in steps])
    n = len(samples)
    scale = np.array([c.scale for c in config.channels])
    offset = np.array([c.offset for c in config.channels])
    acc = (samples["code"].astype(np.float64) - offset) * scale
    acc = np.ascontiguousarray(np.where(usable(samples), acc, np.nan))
    angles = np.asarray(config.angles_rad)
    bs = BATCH_SAMPLES

    def core() -> int:
        valid = 0
        for i in range(0, n, bs):
            valid += int(
                fuse(acc[i : i + bs], angles, config.g, config.tolerance_permil).valid.sum()
            )
        return valid

    dt, valid = timed(core, repeat)
    figures = [
        Figure(
            "fusion_core",
            "fusion core (reference method)",
            n / dt,
            "samples/s",
            target=FUSION_TARGET,
            detail=f"{n} samples in batches of {bs}, {dt * 1e3:.0f} ms (best of {repeat}); "
            f"{valid} valid",
        )
    ]

    def full() -> int:
        p = Pipeline(config)
        k = 0
        for step_samples, speed in steps:
            res, _ = p.compute(step_samples, speed)
            k += len(res)
        return k

    dt, k = timed(full, max(1, repeat - 2))
    figures.append(
        Figure(
            "fusion_estimator",
            "fusion + estimator (Pipeline.compute)",
            k / dt,
            "samples/s",
            detail=f"reference method, estimator (with SPEED_REF) and result rows; {k} samples "
            f"in replay's steps, {dt * 1e3:.0f} ms",
        )
    )
    return figures
