"""The estimator speed benchmark (benchmarks/estimator_speed.py) measures what it says: its
kernel-only runs drive the compiled filter through today's signature, and its drift runs do
have the drift copies running (it asserts so itself). No timing is asserted here."""

from __future__ import annotations

import numpy as np

from benchmarks.estimator_speed import joint_filter_rate, live_push_costs


def test_the_kernel_runs_with_and_without_the_drift_copies() -> None:
    for drift in (False, True):
        assert joint_filter_rate(n=20_000, batch=5000, drift=drift) > 0.0


def test_live_pushes_are_timed_while_the_drift_copies_run() -> None:
    plain, drifting = live_push_costs(), live_push_costs(drift=True)
    assert len(plain) == 6000 - 200
    assert 0.9 * len(plain) < len(drifting) <= len(plain)
    assert np.isfinite(drifting).all() and (drifting >= 0.0).all()
