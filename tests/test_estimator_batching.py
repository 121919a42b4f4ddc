"""The same stream cut into batches differently gives bit-identical estimator output.

A live run pushes a frame or a few at a time, a replay a million; the results (and the
estimator's events) must agree to the last bit, or a replay could not vouch for a run.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bench.config import Config
from bench.fusion.isolation import ResidualIsolator
from bench.fusion.least_squares import geometry
from bench.pipeline.steps import Pipeline
from bench.records.events import EventKind
from devices.base import SourceBatch
from devices.emulator import scenario_from_dict, simulate

FAULTY = {
    "seed": 11,
    "duration_s": 40.0,
    "vertical_curve_m": 60.0,
    "track": [
        {"length_m": 150.0, "gradient_permil": 0.0},
        {"length_m": 200.0, "gradient_permil": 18.0},
        {"length_m": 2000.0, "gradient_permil": -6.0},
    ],
    "train": [
        {"duration_s": 3.0},
        {"duration_s": 12.0, "accel_mps2": 0.8},
        {"duration_s": 10.0},
        {"duration_s": 15.0, "accel_mps2": -0.6},
    ],
    "channels": [{"noise_mps2": 0.002, "vibration_mps2": 0.01, "vibration_hz": 9.0}] * 3,
    "odometer": {"time0_ticks": 60000, "drift_ppm": 120.0},
    "faults": [
        {"channel": 3, "kind": "stuck", "start_s": 4.0, "end_s": 7.0},
        {"channel": 1, "kind": "spike", "start_s": 8.0, "end_s": 11.0, "rate_hz": 4.0},
        {"channel": 2, "kind": "status", "start_s": 12.0, "end_s": 13.0},
        {"channel": 1, "kind": "drift", "start_s": 14.0, "end_s": 20.0},
        {"channel": "bus", "kind": "loss", "start_s": 20.0, "end_s": 24.0, "probability": 0.05},
        {"channel": "bus", "kind": "reorder", "start_s": 24.0, "end_s": 28.0},
        {"channel": 3, "kind": "crc", "start_s": 28.0, "end_s": 30.0, "probability": 0.3},
        {"channel": "speed", "kind": "dropout", "start_s": 31.0, "end_s": 33.0},
    ],
}


def run_in_batches(frames: np.ndarray, sizes: list[int]) -> tuple[np.ndarray, np.ndarray]:
    pipe = Pipeline(Config())
    results, events = [], []
    pos = 0
    for size in sizes:
        if pos >= len(frames):
            break
        step = pipe.process(SourceBatch(frames[pos : pos + size]))
        results.append(step.results)
        events.append(step.events)
        pos += size
    assert pos >= len(frames)
    step = pipe.finish()
    ev = np.concatenate([*events, step.events])
    ev = ev[np.isin(ev["kind"], [EventKind.EXCLUDED, EventKind.READMITTED])]
    return np.concatenate([*results, step.results]), ev[np.lexsort((ev["channel"], ev["n"]))]


@pytest.mark.parametrize("receive_times", ["finite", "nan"])
def test_random_batches_give_bit_identical_results(receive_times: str) -> None:
    frames = simulate(scenario_from_dict(FAULTY)).frames.copy()
    if receive_times == "nan":  # a raw capture: no receive times at all
        frames["t"] = np.nan
    whole, whole_ev = run_in_batches(frames, [len(frames)])
    rng = np.random.default_rng(7)
    sizes = [1] * 900 + rng.integers(1, 400, size=len(frames)).tolist()  # live, then bursts
    cut, cut_ev = run_in_batches(frames, sizes)
    assert len(whole) == len(cut) > 7000
    assert whole.tobytes() == cut.tobytes()
    assert whole_ev.tobytes() == cut_ev.tobytes()
    # and the run exercised what it should
    assert set(whole_ev["value"][whole_ev["kind"] == EventKind.EXCLUDED]) >= {2, 3, 4}
    assert np.isfinite(whole["gradient_signed"]).mean() > 0.6  # faults and a dropout withhold
    assert np.isnan(whole["a_ref"]).any() and (whole["a_ref"] == 0.0).any()


def test_stuck_detector_remembers_channels_across_a_batch_ending_with_them_missing():
    """Regression: a batch ending on a sample without ch1/ch3 must not make their return
    look like a first appearance (a 'change') in the next batch."""
    from bench.fusion.isolation import StuckDetector

    codes = np.tile(np.array([[5], [6], [7]]), (1, 8))  # channel-major (3, N)
    present = np.ones((3, 8), dtype=bool)
    present[:, 3] = [False, True, False]
    ticks = np.arange(8) * 50
    whole = StuckDetector(100).push(ticks, codes, present)
    split = StuckDetector(100)
    parts = [
        split.push(ticks[:4], codes[:, :4], present[:, :4]),
        split.push(ticks[4:], codes[:, 4:], present[:, 4:]),
    ]
    assert np.array_equal(np.concatenate(parts, axis=1), whole)
    assert not whole.any()  # nothing changes at all: nothing is stuck


@pytest.mark.parametrize("window", [1, 3, 50])
def test_residual_isolator_gives_the_same_bits_however_the_stream_is_cut(window: int) -> None:
    """Windows of one sample, shorter than a push, longer than several: one push of all,
    against pushes of random pieces, live-sized (1-3 samples) and longer."""
    config = Config()
    angles = np.array(config.angles_rad)
    rng = np.random.default_rng(window)
    n = 600
    acc = 0.3 * np.cos(angles) + config.g * np.sin(0.01 + angles) + rng.normal(0, 1e-3, (n, 3))
    acc[200:400, 1] += 0.08  # ch2 biased: the residual alarms and singles it out
    cand = rng.random(n) > 0.1
    a_ref = np.full(n, 0.3)
    a_ref[rng.random(n) < 0.2] = np.nan  # the pairs' miss of g then uses w alone
    acc_t = np.where(cand, acc.T, 0.0)  # channel-major, as the estimator passes it

    def isolator() -> ResidualIsolator:
        return ResidualIsolator(geometry(config.angles_rad), config.g, 0.02, window)

    whole_residual, whole_single = isolator().push(acc_t, cand, a_ref)
    assert set(whole_single[200:400].tolist()) >= {1}
    iso = isolator()
    residual, single = [], []
    live = rng.random(n) < 0.5  # half the pieces live-sized, the others up to two windows
    cuts = np.cumsum(np.where(live, rng.integers(1, 4, n), rng.integers(1, 2 * window + 4, n)))
    for lo, hi in itertools.pairwise([0, *cuts[cuts < n].tolist(), n]):
        r, s = iso.push(acc_t[:, lo:hi], cand[lo:hi], a_ref[lo:hi])
        residual += r.tolist()
        single += s.tolist()
    assert np.array(residual).tobytes() == whole_residual.tobytes()
    assert single == whole_single.tolist()
