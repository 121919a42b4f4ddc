"""The drift copies (bench.fusion.joint_drift): a slowly drifting channel is told apart from
the other two before the isolation's residual alarm, against the emulator's truth.

Independent expectations: the truth's gradient, the channel the fault was put on, and the
isolation's own alarm (issue 7's residual test) for when the exclusion comes.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.config import Config, EstimatorSettings
from tests.test_estimator_scenarios import run

RATE = 0.005  # m/s^2 per s: a temperature drift, about 7 s to the residual alarm on ch1/ch3


def drift_run(channel: int, llr: float) -> tuple[np.ndarray, np.ndarray]:
    res, _, truth = run(
        {
            "duration_s": 13.0,
            "initial_speed_mps": 15.0,
            "speed_ref": True,
            "track": [{"length_m": 1000.0, "gradient_permil": 20.0}],
            "channels": [{"noise_mps2": 0.0098}] * 3,  # 1 mg
            "odometer": {"noise_mps": 0.005, "resolution_mps": 0.02, "lag_s": 0.03},
            "faults": [
                {"channel": channel, "kind": "drift", "start_s": 4.0, "rate_mps2_per_s": RATE}
            ],
        },
        Config(estimator=EstimatorSettings(drift_llr=llr)),
    )
    return res, truth


@pytest.mark.parametrize("channel", [1, 3])
def test_a_drifting_channel_is_named_by_the_copies_before_the_alarm(channel: int) -> None:
    on, truth = drift_run(channel, EstimatorSettings().drift_llr)
    off, _ = drift_run(channel, 0.0)
    t = on["time_s"]
    excluded = np.flatnonzero(on["excluded"] == channel)
    assert len(excluded)  # the isolation still excludes it, as before
    window = (t > 7.0) & (t < t[excluded[0]])  # drifting for 3 s, not yet excluded
    assert window.sum() > 500  # over 2.5 s of it at 200 Hz
    given_on = np.isfinite(on["gradient_signed"][window])
    given_off = np.isfinite(off["gradient_signed"][window])
    # without the copies the worst-case sigma withholds most of the window; with them the
    # copy without the drifting channel gives the gradient for most of it ...
    assert given_on.mean() > 0.75
    assert given_on.mean() > given_off.mean() + 0.3
    # ... and what it gives is right (the drift reaches 0.02-0.04 m/s^2, 2-4 permil, here)
    err = (on["gradient_signed"] - truth["gradient_permil"])[window][given_on]
    assert np.max(np.abs(err)) < 0.5


def test_at_standstill_the_copies_name_no_channel_they_cannot_tell_apart() -> None:
    """At rest u is s alone and the odometer says 0 for every copy: nothing tells ch1 from
    ch3, so no copy may take over (the worst-case sigma stays), and nothing wrong is given."""
    res, truth = run(
        {
            "duration_s": 12.0,
            "initial_speed_mps": 0.0,
            "speed_ref": True,
            "track": [{"length_m": 1000.0, "gradient_permil": 20.0}],
            "channels": [{"noise_mps2": 0.0098}] * 3,
            "odometer": {"noise_mps": 0.005, "resolution_mps": 0.02},
            "faults": [{"channel": 1, "kind": "drift", "start_s": 4.0, "rate_mps2_per_s": RATE}],
        }
    )[::2]
    err = res["gradient_signed"] - truth["gradient_permil"]
    given = np.isfinite(err)
    assert np.max(np.abs(err[given & (res["time_s"] > 1.0)])) < 0.3


def test_the_copies_give_the_same_bits_however_the_stream_is_cut() -> None:
    """Live pushes (a few frames at a time) and one replay batch, through a drift the copies
    name: the copies' state is carried between pushes like the filter's."""
    from bench.pipeline.steps import Pipeline
    from devices.base import SourceBatch
    from devices.emulator import scenario_from_dict, simulate

    sim = simulate(
        scenario_from_dict(
            {
                "duration_s": 11.0,
                "initial_speed_mps": 15.0,
                "track": [{"length_m": 1000.0, "gradient_permil": 20.0}],
                "channels": [{"noise_mps2": 0.0098}] * 3,
                "odometer": {"noise_mps": 0.005, "resolution_mps": 0.02},
                "body_modes": {"enabled": False},  # pinned before the body modes (issue 25)
                "faults": [
                    {"channel": 3, "kind": "drift", "start_s": 3.0, "rate_mps2_per_s": RATE}
                ],
            }
        )
    )

    def results(cut: int) -> np.ndarray:
        pipe = Pipeline(Config())
        frames = sim.frames
        steps = [pipe.process(SourceBatch(frames[i : i + cut])) for i in range(0, len(frames), cut)]
        steps.append(pipe.finish())
        return np.concatenate([s.results for s in steps if len(s.results)])

    whole, pieces = results(len(sim.frames)), results(7)
    assert np.isfinite(whole["gradient_signed"][whole["time_s"] > 8.0]).mean() > 0.5  # named
    for col in ("gradient_signed", "gradient_sigma"):
        assert whole[col].tobytes() == pieces[col].tobytes(), col
