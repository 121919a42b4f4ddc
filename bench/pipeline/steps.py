"""The pipeline: source batches in, samples, results and events out. One for live and replay.

decode (protocol.batch) -> assemble (bench.pipeline.assembly) -> reference fusion + estimator.
Stateful across batches, and its output does not depend on how the stream is batched,
so a live run and the replay of its log give the same rows bit for bit.

A live step carries a few frames and usually nothing else, so every stage returns early
(shared empty arrays) when it has nothing to do: the processing thread shares the GIL
with acquisition and logging, and its fixed cost per step is the live latency.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from bench.config import Config
from bench.fusion.estimator import ESTIMATE_DTYPE, Estimator
from bench.fusion.reference import fuse
from bench.pipeline.assembly import Assembler
from bench.pipeline.stats import Stats
from bench.records.arrays import concat_records
from bench.records.board import SPEED_DTYPE, STATUS_DTYPE, speed_records, status_records
from bench.records.events import EVENT_DTYPE, NO_EVENTS, EventKind, concat_events, make_events
from bench.records.model import NO_MODEL_ROWS
from bench.records.results import RESULT_DTYPE
from bench.records.samples import NO_SAMPLES, SAMPLE_DTYPE, usable
from devices.base import SourceBatch
from protocol.batch import EMPTY_DECODED, DecodedBatch, decode_batch
from protocol.frames import empty_frames

_NOTICE_KINDS = {
    "parse_error": EventKind.PARSE_ERROR,
    "truncated": EventKind.PARSE_ERROR,
    "disconnect": EventKind.DISCONNECT,
    "reconnect": EventKind.RECONNECT,
    "overflow": EventKind.SOCKET_OVERFLOW,  # value: the notice's count of frames lost
}
_VOTE_FAIL, _INVALID = int(EventKind.VOTE_FAIL), int(EventKind.INVALID)
_NO_RESULTS = np.zeros(0, dtype=RESULT_DTYPE)
_NO_FRAMES = empty_frames()


class _ByteRuns:
    """Copies the named fields of one structured dtype into another as raw byte runs
    (fields adjacent in both merged into one run): a byte copy per run instead of a typed,
    unaligned copy per field, which is what dominates building a packed structured array."""

    def __init__(self, dst: np.dtype, src: np.dtype, names: list[str]) -> None:
        self.dst, self.src, self.names = dst, src, names
        runs: list[list[int]] = []  # [dst offset, src offset, size]
        dst_fields, src_fields = dst.fields, src.fields
        assert dst_fields is not None and src_fields is not None  # structured dtypes
        for name in names:
            (dt, d_off), (st, s_off) = dst_fields[name][:2], src_fields[name][:2]
            assert dt == st, name
            if runs and runs[-1][0] + runs[-1][2] == d_off and runs[-1][1] + runs[-1][2] == s_off:
                runs[-1][2] += dt.itemsize
            else:
                runs.append([d_off, s_off, dt.itemsize])
        self.dst_view, self.src_view = (
            np.dtype(
                {
                    "names": [f"r{i}" for i in range(len(runs))],
                    "formats": [f"V{r[2]}" for r in runs],
                    "offsets": [r[k] for r in runs],
                    "itemsize": dtype.itemsize,
                }
            )
            for k, dtype in ((0, dst), (1, src))
        )

    def copy(self, dst: np.ndarray, src: np.ndarray) -> None:
        if dst.dtype != self.dst or src.dtype != self.src:  # not the layouts planned for
            for name in self.names:
                dst[name] = src[name]
            return
        d, s = dst.view(self.dst_view), src.view(self.src_view)
        for name in self.dst_view.names or ():
            d[name] = s[name]


_FROM_SAMPLE = _ByteRuns(
    RESULT_DTYPE, SAMPLE_DTYPE, ["n", "seq", "ticks", "t", "code", "status", "present"]
)
_FROM_ESTIMATE = _ByteRuns(RESULT_DTYPE, ESTIMATE_DTYPE, list(ESTIMATE_DTYPE.names or ()))


@dataclass(slots=True)
class StepOutput:
    """Everything one pipeline step produced; sinks take what they need."""

    frames: np.ndarray = field(default_factory=empty_frames)  # as received
    outcome: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))  # per frame
    seq0: int = 0  # arrival index of frames[0]
    samples: np.ndarray = field(default_factory=lambda: np.zeros(0, SAMPLE_DTYPE))
    results: np.ndarray = field(default_factory=lambda: np.zeros(0, RESULT_DTYPE))
    events: np.ndarray = field(default_factory=lambda: np.zeros(0, EVENT_DTYPE))
    status: np.ndarray = field(default_factory=lambda: np.zeros(0, STATUS_DTYPE))
    speed: np.ndarray = field(default_factory=lambda: np.zeros(0, SPEED_DTYPE))
    batch: SourceBatch | None = None
    # the explicit model's rows a live run made meanwhile (`--lag`: bench.live.model)
    model: np.ndarray = field(default_factory=lambda: NO_MODEL_ROWS)


STEP_ARRAYS = ("frames", "outcome", "samples", "results", "events", "status", "speed", "model")
"""The array fields of a StepOutput, in the order the MCAP writer takes them."""


def merge_batches(parts: Sequence[SourceBatch]) -> SourceBatch:
    """One batch holding the parts' frames, link errors and notices, in arrival order."""
    if len(parts) == 1:
        return parts[0]
    return SourceBatch(
        concat_records([p.frames for p in parts]),
        [e for p in parts for e in p.link_errors],
        [n for p in parts for n in p.notices],
    )


def merge_steps(steps: Sequence[StepOutput]) -> StepOutput:
    """Consecutive steps as one: every array field concatenated in order (one bytes join
    each, not np.concatenate), the batches' link errors and notices in order, the first
    step's ``seq0``. The one routine for every place that ships or writes steps in groups."""
    if len(steps) == 1:
        return steps[0]
    arrays = {name: concat_records([getattr(s, name) for s in steps]) for name in STEP_ARRAYS}
    batches = [s.batch for s in steps if s.batch is not None]
    batch = SourceBatch(
        arrays["frames"],
        [e for b in batches for e in b.link_errors],
        [n for b in batches for n in b.notices],
    )
    return StepOutput(**arrays, seq0=steps[0].seq0, batch=batch)


class EstimatorLike(Protocol):
    """What the pipeline asks of the estimator (bench.fusion.estimator.Estimator; the
    preview pipeline's stand-in while its kernel is prepared, bench.pipeline.warmup)."""

    def push(
        self, samples: np.ndarray, acc: np.ndarray, usable: np.ndarray, speeds: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]: ...


class Pipeline:
    def __init__(self, config: Config, *, estimator: EstimatorLike | None = None) -> None:
        self.config = config
        self.assembler = Assembler(config.sample_rate_hz)
        self.estimator: EstimatorLike = estimator if estimator is not None else Estimator(config)
        self.stats = Stats()
        self.seq = 0  # frames seen so far (arrival index of the next one)
        self.first_ticks: int | None = None
        self.tolerance_permil = config.tolerance_permil
        self._angles = np.asarray(config.angles_rad, dtype=np.float64)
        self._scale = np.array([c.scale for c in config.channels], dtype=np.float64)
        self._offset = np.array([c.offset for c in config.channels], dtype=np.float64)
        self._last_fail_mask = 0
        self.last_status: np.void | None = None
        self.last_speed: np.void | None = None

    # -- stream ----------------------------------------------------------------------------
    def process(self, batch: SourceBatch) -> StepOutput:
        frames = batch.frames
        dec = decode_batch(frames, self.config.base_id)
        seq0 = self.seq
        self.seq += len(frames)
        self.stats.count_frames(dec.can_id)
        samples, events = self.assembler.push(frames["t"], dec, seq0)
        return self._fuse(samples, events, frames, dec, seq0, batch)

    def finish(self) -> StepOutput:
        samples, events = self.assembler.finish()
        return self._fuse(samples, events, _NO_FRAMES, EMPTY_DECODED, self.seq, None)

    # -- internals -------------------------------------------------------------------------
    def _fuse(
        self,
        samples: np.ndarray,
        events: np.ndarray,
        frames: np.ndarray,
        dec: DecodedBatch,
        seq0: int,
        batch: SourceBatch | None,
    ) -> StepOutput:
        t = frames["t"]
        status = status_records(t, dec, seq0)
        speed = speed_records(t, dec, seq0)
        results, fusion_events = self.compute(samples, speed)
        parts = [events, fusion_events]
        if batch is not None and (batch.link_errors or batch.notices):
            parts.append(self._source_events(batch))
        if len(status):
            parts.append(self._state_events(status))
            self.last_status = status[-1]
            self.stats.status_frames += len(status)
        if len(speed):
            self.last_speed = speed[-1]
            self.stats.speed_frames += len(speed)
        all_events = concat_events(parts)
        self.stats.count_events(all_events)
        self.stats.count_results(results)
        self.stats.count_channel_frames(t, dec)
        return StepOutput(
            frames, dec.outcome, seq0, samples, results, all_events, status, speed, batch
        )

    def compute(self, samples: np.ndarray, speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fusion of emitted samples: reference method + estimator."""
        if len(samples) == 0:
            if len(speed) == 0:  # nothing to fuse and nothing for the estimator to keep
                return _NO_RESULTS, NO_EVENTS
            _, est_events = self.estimator.push(
                NO_SAMPLES, np.zeros((0, 3)), np.zeros((0, 3), bool), speed
            )
            return _NO_RESULTS, est_events
        if self.first_ticks is None:
            self.first_ticks = int(samples["ticks"][0])
        res = np.empty(len(samples), dtype=RESULT_DTYPE)  # every field is written below
        _FROM_SAMPLE.copy(res, samples)
        res["time_s"] = (samples["ticks"] - self.first_ticks) / 10000.0
        ok = usable(samples)
        acc = (samples["code"].astype(np.float64) - self._offset) * self._scale
        acc_usable = np.where(ok, acc, np.nan)
        res["acc"] = acc_usable
        ref = fuse(acc_usable, self._angles, self.config.g, self.tolerance_permil)
        res["slopes"] = ref.slopes
        res["votes"] = ref.votes
        res["weights"] = ref.weights
        res["gradient"] = ref.gradient
        res["valid"] = ref.valid
        est, est_events = self.estimator.push(samples, acc, ok, speed)
        _FROM_ESTIMATE.copy(res, est)
        vote_events = self._vote_events(samples["t"], samples["n"], ref.votes)
        return res, concat_events([vote_events, est_events])

    def _vote_events(self, t: np.ndarray, n: np.ndarray, votes: np.ndarray) -> np.ndarray:
        """A VOTE_FAIL event whenever the set of failed votes changes to a non-empty one
        (value: failed votes as bits 1, 2, 4), and INVALID when it becomes all three."""
        v = votes.view(np.uint8)
        mask = 7 - (v[:, 0] | v[:, 1] << 1 | v[:, 2] << 2).astype(np.int64)
        prev = np.empty_like(mask)
        prev[0] = self._last_fail_mask
        prev[1:] = mask[:-1]
        self._last_fail_mask = int(mask[-1])
        idx = np.flatnonzero((mask != prev) & (mask != 0))
        if len(idx) == 0:
            return NO_EVENTS
        m = mask[idx]
        inv = idx[m == 7]
        return concat_events(
            [
                make_events(EventKind.VOTE_FAIL, t[idx], 0, n[idx], m),
                make_events(EventKind.INVALID, t[inv], 0, n[inv]),
            ]
        )

    def _state_events(self, status: np.ndarray) -> np.ndarray:
        prev_state = -1 if self.last_status is None else int(self.last_status["state"])
        states = status["state"].astype(np.int64)
        prev = np.concatenate(([prev_state], states[:-1]))
        ch = states != prev
        return make_events(EventKind.BOARD_STATE, status["t"][ch], 0, -1, states[ch])

    def _source_events(self, batch: SourceBatch) -> np.ndarray:
        parts = []
        if batch.link_errors:
            le = batch.link_errors
            parts.append(
                make_events(
                    EventKind.LINK_ERROR,
                    np.array([e.t for e in le], dtype=np.float64),
                    0,
                    -1,
                    np.array([int(e.outcome) for e in le]),
                )
            )
        for notice in batch.notices:
            kind = _NOTICE_KINDS.get(notice.kind)
            if kind is not None:
                parts.append(make_events(kind, notice.t, 0, -1, notice.count))
        return concat_events(parts)
