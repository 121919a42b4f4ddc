"""A long faulty stream through the whole Pipeline gives the same bytes however it is cut.

Live runs feed the pipeline a frame or a few at a time, replay feeds it tens of thousands,
through the same code; a mix of both happens after a stall. Every output array must agree
to the byte, or a replay could not vouch for a run. Events are compared as a multiset: each
step orders its own events by time, so where a step boundary falls may reorder equal-time
events.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.config import Config
from bench.pipeline.steps import Pipeline, StepOutput
from bench.records.events import EventKind
from devices.base import SourceBatch
from devices.emulator import scenario_from_dict, simulate
from protocol.crc import frame_crc8_batch
from protocol.records import FLAG_EXTENDED

FAULTS = [
    {"channel": "status", "kind": "dropout", "start_s": 0.0, "end_s": 0.3},
    {"channel": 3, "kind": "dropout", "start_s": 0.5, "end_s": 0.8},
    {"channel": "bus", "kind": "loss", "start_s": 1.0, "end_s": 1.6, "probability": 0.2},
    {"channel": "bus", "kind": "duplicate", "start_s": 1.6, "end_s": 2.2, "probability": 0.2},
    {"channel": "bus", "kind": "reorder", "start_s": 2.2, "end_s": 2.8, "probability": 0.3},
    {"channel": "adc", "kind": "crc", "start_s": 2.8, "end_s": 3.1, "probability": 0.3},
    {"channel": 2, "kind": "counter_jump", "start_s": 3.1, "end_s": 3.2},
    {"channel": 1, "kind": "status", "start_s": 3.3, "end_s": 3.6},
    {"channel": 3, "kind": "stuck", "start_s": 3.6, "end_s": 4.6},
    {"channel": 2, "kind": "spike", "start_s": 0.5, "end_s": 2.5, "rate_hz": 5.0},
    {"channel": 1, "kind": "drift", "start_s": 4.6, "end_s": 5.5},
    {"channel": 3, "kind": "saturate", "start_s": 5.5, "end_s": 5.8},
    {"channel": "speed", "kind": "dropout", "start_s": 1.5, "end_s": 2.0},
    {"channel": "bus", "kind": "loss", "start_s": 5.8, "end_s": 6.0, "probability": 0.7},
]


def faulty_frames(rate: int, seed: int) -> np.ndarray:
    """The emulator's stream with every frame fault kind, plus what no board sends: foreign
    ids, wrong lengths, extended frames, and absurd receive times."""
    scenario = {
        "seed": seed,
        "duration_s": 6.0,
        "sample_rate_hz": rate,
        "faults": FAULTS,
        "track": [
            {"length_m": 40.0, "gradient_permil": 0.0},
            {"length_m": 400.0, "gradient_permil": 25.0},
        ],
        "train": [{"duration_s": 1.0}, {"duration_s": 5.0, "accel_mps2": 0.7}],
    }
    frames = simulate(scenario_from_dict(scenario)).frames.copy()
    rng = np.random.default_rng(seed)
    junk = frames[rng.integers(0, len(frames), 30)].copy()
    junk["id"][:10] = 0x7F0  # unknown id
    junk["dlc"][10:20] = 5  # wrong length of a board id
    junk["flags"][20:] = FLAG_EXTENDED  # the board's id, but an extended frame
    frames = np.insert(frames, np.sort(rng.integers(0, len(frames), 30)), junk)
    frames["t"][rng.integers(0, len(frames), 4)] = [np.nan, np.inf, 0.0, 1e15]
    # the time axis: a host clock step, a frame stamped early, a CRC-valid wild board time
    frames["t"][len(frames) // 3 :] += 5.0
    adc_rows = np.flatnonzero((frames["id"] >= 0x101) & (frames["id"] <= 0x103))
    frames["t"][adc_rows[len(adc_rows) // 2]] -= 7.5
    wild = adc_rows[2 * len(adc_rows) // 3]
    ts = (int(frames["data"][wild, 5]) | int(frames["data"][wild, 6]) << 8) + 30000
    frames["data"][wild, 5:7] = (ts & 0xFF, (ts >> 8) & 0xFF)
    data = np.ascontiguousarray(frames["data"][wild : wild + 1])
    frames["data"][wild, 7] = frame_crc8_batch(
        frames["id"][wild : wild + 1].astype(np.int64), data
    )[0]
    return frames


def run(frames: np.ndarray, sizes: list[int], rate: int) -> tuple[list[StepOutput], Pipeline]:
    pipe = Pipeline(Config(sample_rate_hz=rate))
    steps, pos = [], 0
    for size in sizes:
        if pos >= len(frames):
            break
        steps.append(pipe.process(SourceBatch(frames[pos : pos + size])))
        pos += size
    assert pos >= len(frames)
    steps.append(pipe.finish())
    return steps, pipe


def joined(steps: list[StepOutput], name: str) -> np.ndarray:
    return np.concatenate([getattr(s, name) for s in steps])


def canonical(events: np.ndarray) -> np.ndarray:
    """Events in one fixed order (by their bytes), to compare as a multiset."""
    rows = events.view(np.uint8).reshape(len(events), -1)
    return rows[np.lexsort(rows.T[::-1])]


def sizes_for(kind: str, n: int, rng: np.random.Generator) -> list[int]:
    if kind == "whole":
        return [n]
    if kind == "random":  # live-sized, bursts, and replay-sized
        return rng.choice([1, 2, 3, 5, 16, 17, 40, 64, 65, 200, 3000], size=n).tolist()
    return [int(kind)] * n


@pytest.mark.parametrize(("rate", "seed"), [(1000, 1), (200, 2)])
def test_any_batching_gives_the_same_bytes(rate: int, seed: int) -> None:
    frames = faulty_frames(rate, seed)
    rng = np.random.default_rng(seed)
    ref_steps, ref_pipe = run(frames, [len(frames)], rate)
    ref_events = joined(ref_steps, "events")
    for kind in ("1", "3", "random"):
        steps, pipe = run(frames, sizes_for(kind, len(frames), rng), rate)
        for name in ("outcome", "samples", "results", "status", "speed"):
            assert joined(steps, name).tobytes() == joined(ref_steps, name).tobytes(), (
                kind,
                name,
            )
        events = joined(steps, "events")
        assert canonical(events).tobytes() == canonical(ref_events).tobytes(), kind
        assert pipe.stats.as_dict() == ref_pipe.stats.as_dict(), kind
        assert pipe.stats.events == ref_pipe.stats.events, kind
        for mine, ref in zip(pipe.stats.channels, ref_pipe.stats.channels, strict=True):
            assert (mine.first_t, mine.last_t) == (ref.first_t, ref.last_t), kind
        assert [s.seq0 for s in steps] == np.cumsum([0, *[len(s.frames) for s in steps]])[
            :-1
        ].tolist()
    # and the stream exercised what it should: every kind of event the faults cause
    seen = {EventKind(k) for k in ref_events["kind"].tolist()}
    assert seen >= {
        EventKind.CRC_ERROR,
        EventKind.WRONG_DLC,
        EventKind.UNKNOWN_ID,
        EventKind.DUPLICATE,
        EventKind.GAP,
        EventKind.SAMPLES_LOST,
        EventKind.COUNTER_JUMP,
        EventKind.STATUS_FLAG,
        EventKind.VOTE_FAIL,
        EventKind.EXCLUDED,
        EventKind.BOARD_STATE,
        EventKind.OUTLIER,
        EventKind.TIME_OUTLIER,
        EventKind.CLOCK_STEP,
    }
    assert len(joined(ref_steps, "results")) > 0.9 * rate * 6.0
