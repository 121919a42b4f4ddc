"""Where each plain-Python twin takes over from its vectorised path: every threshold in one place.

Live steps are a few frames, replay steps 65 536. numpy's fixed cost per call (~1-5 us)
dominates the first, so each stage below has a plain-Python twin with the same expressions
in the same order, and takes it for a batch up to its threshold; the outputs are identical
byte for byte either way (tests/test_pipeline_batching.py, test_estimator_batching.py), so a threshold moves speed only.
Each is about where the two paths cost the same for that stage.

Decode, assembly, the row helpers and the running counters have one path for any batch length.
The estimator's twin (16 samples) is set beside it in bench.fusion.estimator (SCALAR_MAX).
"""

from __future__ import annotations

__all__ = [
    "FUSION_SAMPLES",
]

FUSION_SAMPLES = 16
"""Samples the pipeline fuses with the scalar twin (reference method and result rows; a live
step has one or two)."""
