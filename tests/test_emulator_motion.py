"""Invariants of jerk-limited motion (devices.emulator.motion) over many random phase lists:
the jerk never exceeds its limit except at a hard stop, speed and position are continuous,
no phase without allow_reverse takes the speed through zero, and a very large jerk limit
gives the constant-acceleration model's motion. The hand-computed cases are in
test_emulator_realism.py."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from devices.emulator.motion import jerk_limited_pieces
from devices.emulator.scenario import TrainPhase
from devices.emulator.world import train_motion

phases = st.lists(
    st.builds(
        TrainPhase,
        duration_s=st.floats(0.1, 20.0),
        accel_mps2=st.sampled_from([-1.2, -0.5, 0.0, 0.3, 1.0]),
        allow_reverse=st.booleans(),
    ),
    min_size=1,
    max_size=5,
)


@settings(max_examples=60, deadline=None)
@given(
    ph=phases,
    v0=st.sampled_from([0.0, 5.0, -3.0, 15.0]),
    jerk=st.sampled_from([0.3, 0.8, 2.0]),
)
def test_jerk_limited_motion_invariants(ph: list[TrainPhase], v0: float, jerk: float) -> None:
    ph_t = tuple(ph)
    total = sum(p.duration_s for p in ph_t) + 5.0
    t = np.linspace(0.0, total, 8001)
    dt = t[1] - t[0]
    a, v, x = jerk_limited_pieces(ph_t, jerk, v0, 0.0, total).evaluate(t)
    stop = (v[1:] == 0.0) | (v[:-1] == 0.0)  # a hard stop may drop a to 0 at once
    j = np.where(stop, 0.0, np.diff(a) / dt)
    assert np.abs(j).max() <= jerk * 1.0001
    assert np.abs(np.diff(x) / dt - 0.5 * (v[1:] + v[:-1])).max() < 1e-3
    dv = np.where(stop, 0.0, np.abs(np.diff(v) / dt - 0.5 * (a[1:] + a[:-1])))
    assert dv.max() < 1e-2 * jerk
    start = 0.0
    for p in ph_t:
        sel = (t >= start) & (t < start + p.duration_s)
        if not p.allow_reverse and sel.any():
            first = v[sel][0]
            if first > 1e-9:
                assert v[sel].min() >= -1e-9
            if first < -1e-9:
                assert v[sel].max() <= 1e-9
        start += p.duration_s
    _, v_step, x_step = jerk_limited_pieces(ph_t, 1e5, v0, 0.0, total).evaluate(t)
    m = train_motion(ph_t, v0, 0.0, t)
    assert np.abs(v_step - m.speed_mps).max() < 1e-3
    assert np.abs(x_step - m.position_m).max() < 1e-2


def test_a_stop_is_exactly_zero_so_the_next_phase_does_not_reverse() -> None:
    """Backwards at 3 m/s, +1 m/s^2 for 3.34375 s (through zero: allowed) leaves +0.34375
    m/s; braking at -1.2 m/s^2 without reversing stops the train after 0.2865 s, and the
    next braking phase must leave it standing (a rounding residue of -5e-17 m/s once read
    as 'running backwards' and let it reverse to -1.2 m/s)."""
    ph = (
        TrainPhase(duration_s=3.34375, accel_mps2=1.0, allow_reverse=True),
        TrainPhase(duration_s=1.0, accel_mps2=-1.2, allow_reverse=False),
        TrainPhase(duration_s=1.0, accel_mps2=-1.2, allow_reverse=False),
    )
    t = np.array([3.34375, 3.34375 + 0.34375 / 1.2, 4.5, 5.34375, 9.0])
    m = train_motion(ph, -3.0, 0.0, t)
    assert m.speed_mps[0] == pytest.approx(0.34375)
    assert abs(m.speed_mps[1]) < 1e-12  # the stop instant, within a rounding residue
    assert m.speed_mps[2:].tolist() == [0.0, 0.0, 0.0]
