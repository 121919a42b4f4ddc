"""The model's forward pass as a stream and the fixed-lag smoother on it (issue 26, live).

Expectations are independent of the stream: the replay's path (ModelLog.smooth, one pass
over the whole run's arrays) that a live run must repeat to the bit whatever the cut, and
the emulated track's gradient (written into the scenario here) that the lagged estimate,
which has seen more, must come closer to than the filter.
"""

from __future__ import annotations

import itertools
import tomllib

import numpy as np
import pytest

from bench.config import Config, config_from_dict
from bench.fusion.model import state
from bench.fusion.model.log import ModelLog, gradient_permil
from bench.fusion.model.stream import Blocks, FixedLag, ForwardStream, Lagged
from bench.pipeline.steps import Pipeline
from bench.replay.run import run_steps
from devices.base import SourceBatch
from devices.emulator import calibration_toml, simulate
from devices.emulator.scenario import parse_scenario

GRADIENT = 12.0  # permil, the whole line
SCENARIO = f"""
description = "an acceleration, a cruise and a braking on a {GRADIENT} permil grade"
seed = 11
duration_s = 36.0
sample_rate_hz = 100
speed_ref = true
jerk_mps3 = 0.8
track = [{{ length_m = 3000.0, gradient_permil = {GRADIENT} }}]
train = [
    {{ duration_s = 4.0 }},
    {{ duration_s = 10.0, accel_mps2 = 1.0 }},
    {{ duration_s = 8.0 }},
    {{ duration_s = 10.0, accel_mps2 = -0.9 }},
    {{ duration_s = 4.0 }},
]
[odometer]
lag_s = 0.03
noise_mps = 0.005
wheel_diameter_error = 0.01
[body_modes]
enabled = false
"""

Push = tuple[np.ndarray, np.ndarray, np.ndarray, tuple[np.ndarray, ...] | None]


class _Pushes:
    """Keeps every push the estimator makes to its model log, as given."""

    def __init__(self) -> None:
        self.pushes: list[Push] = []
        self.log = ModelLog()

    def add(self, b, acc, mask, frames, t=None) -> None:  # type: ignore[no-untyped-def]
        keep = None if frames is None else tuple(np.array(c) for c in frames)
        self.pushes.append((np.array(b), np.array(acc), np.array(mask), keep))
        self.log.add(b, acc, mask, frames)


@pytest.fixture(scope="module")
def run() -> tuple[_Pushes, Config]:
    sc = parse_scenario(SCENARIO, "stream.toml")
    sim = simulate(sc)
    config = config_from_dict(tomllib.loads(calibration_toml(sc)), source="stream calibration")
    pipeline = Pipeline(config)
    pushes = _Pushes()
    pipeline.estimator.log = pushes  # type: ignore[attr-defined]  # the real Estimator
    frames = sim.frames
    batches = (SourceBatch(frames[i : i + 777]) for i in range(0, len(frames), 777))
    for _ in run_steps(pipeline, batches):
        pass
    return pushes, config


def _whole(pushes: list[Push]) -> Push:
    """All pushes as one (frames anchored into the whole)."""
    b = np.concatenate([p[0] for p in pushes])
    acc = np.concatenate([p[1].reshape(len(p[0]), 3) for p in pushes])
    mask = np.concatenate([p[2] for p in pushes])
    cols: list[list[np.ndarray]] = [[] for _ in range(5)]
    at = 0
    for p in pushes:
        if p[3] is not None and len(p[3][0]):
            cols[0].append(p[3][0].astype(np.int64) + at)
            for c in range(1, 5):
                cols[c].append(p[3][c])
        at += len(p[0])
    return b, acc, mask, tuple(np.concatenate(c) for c in cols)


def _cut(whole: Push, cuts: np.ndarray) -> list[Push]:
    """``whole`` cut before each sample index in ``cuts``; each frame in the push holding
    its anchor sample (one anchored past the end in the last)."""
    b, acc, mask, frames = whole
    assert frames is not None
    edges = [0, *sorted(set(int(c) for c in cuts)), len(b)]
    out: list[Push] = []
    for j, (lo, hi) in enumerate(itertools.pairwise(edges)):
        last = j == len(edges) - 2
        sel = (frames[0] >= lo) & ((frames[0] < hi) | last)
        f = (frames[0][sel] - lo, *(c[sel] for c in frames[1:]))
        out.append((b[lo:hi], acc[lo:hi], mask[lo:hi], f))
    return out


def _stream(config: Config, pushes: list[Push], lag: int) -> tuple[Blocks, Lagged]:
    fwd, smooth = ForwardStream(config), FixedLag(lag, config.g)
    blocks, lagged = [], []
    for b, acc, mask, frames in pushes:
        got = fwd.push(b, acc, mask, frames)  # type: ignore[arg-type]
        blocks.append(got)
        lagged.append(smooth.push(got))
    last = fwd.finish()
    blocks.append(last)
    lagged += [smooth.push(last), smooth.finish()]
    return (
        Blocks(*(np.concatenate([getattr(k, f) for k in blocks]) for f in Blocks.__slots__)),
        Lagged(*(np.concatenate([getattr(k, f) for k in lagged]) for f in Lagged.__slots__)),
    )


def _bits(a: object, b: object, cls: type) -> None:
    for name in cls.__slots__:  # type: ignore[attr-defined]
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and x.tobytes() == y.tobytes(), name


def test_the_stream_gives_the_replay_s_filtered_gradient_to_the_bit(run) -> None:  # type: ignore[no-untyped-def]
    pushes, config = run
    blocks, _ = _stream(config, pushes.pushes, 0)
    sm = pushes.log.smooth(config)
    n = pushes.log.samples
    assert len(blocks) == (n + 1) // 2  # 100 Hz: blocks of two samples
    grad, sigma = gradient_permil(
        blocks.x_filt[:, state.S], blocks.p_filt[:, state.S, state.S], config.g
    )
    idx = np.arange(n) // 2
    assert sigma[idx].tobytes() == sm.filtered_sigma.tobytes()
    given = np.isfinite(sm.filtered)
    assert given.mean() > 0.5  # the filter alone withholds its first seconds
    assert grad[idx][given].tobytes() == sm.filtered[given].tobytes()


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_stream_and_its_lagged_smoother_do_not_depend_on_the_cut(run, seed: int) -> None:  # type: ignore[no-untyped-def]
    pushes, config = run
    whole = _whole(pushes.pushes)
    one = _stream(config, [whole], 50)
    rng = np.random.default_rng(seed)
    n = len(whole[0])
    for cuts in (rng.integers(0, n, 7), rng.integers(0, n, 400), np.arange(1, n, 3)):
        got = _stream(config, _cut(whole, cuts), 50)
        _bits(got[0], one[0], Blocks)
        _bits(got[1], one[1], Lagged)
    as_pushed = _stream(config, pushes.pushes, 50)
    _bits(as_pushed[0], one[0], Blocks)


def test_a_lag_of_none_is_the_filter_and_every_block_comes_out_once(run) -> None:  # type: ignore[no-untyped-def]
    pushes, config = run
    blocks, lagged = _stream(config, pushes.pushes, 0)
    assert lagged.t.tobytes() == blocks.t.tobytes()
    assert lagged.x.tobytes() == blocks.x_filt.tobytes()
    _, lagged50 = _stream(config, pushes.pushes, 50)
    assert lagged50.t.tobytes() == blocks.t.tobytes()  # the last 50 at the end, given all


def test_the_lagged_gradient_is_closer_to_the_track_than_the_filter_s(run) -> None:  # type: ignore[no-untyped-def]
    pushes, config = run
    blocks, lagged = _stream(config, pushes.pushes, 100)  # 2 s behind
    grad, sigma = gradient_permil(
        blocks.x_filt[:, state.S], blocks.p_filt[:, state.S, state.S], config.g
    )
    late = slice(250, len(blocks) - 100)  # past the first 5 s; blocks given 2 s later
    err_f = grad[late] - GRADIENT
    err_l = lagged.gradient[late] - GRADIENT
    assert np.all(lagged.gradient_sigma[late] <= sigma[late])
    rms_f, rms_l = (float(np.sqrt(np.mean(e**2))) for e in (err_f, err_l))
    assert rms_l < 0.7 * rms_f, (rms_l, rms_f)
    # honest: within three of its own sigma nearly everywhere
    assert np.mean(np.abs(err_l) <= 3.0 * lagged.gradient_sigma[late]) > 0.97
