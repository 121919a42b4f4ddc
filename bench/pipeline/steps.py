"""The pipeline: source batches in, samples, results and events out. One for live and replay.

decode (protocol.batch) -> assemble (bench.pipeline.assembly) -> reference fusion + estimator.
Stateful across batches, and its output does not depend on how the stream is batched,
so a live run and the replay of its log give the same rows bit for bit.

A step is two stages, :meth:`Pipeline.reference` (decode, assembly, the reference method:
every column but the estimator's) and :meth:`Pipeline.estimate` (the estimator's columns and
events, the step's counts); :meth:`Pipeline.process` runs both. A replay runs them in two
threads (bench.replay.run), so the first frames are decoded and fused while the estimator's
kernels load; each stage sees the same calls in the same order either way, so the rows are
the same bits.

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
from bench.fusion.reference import fuse
from bench.pipeline.assembly import Assembler
from bench.pipeline.stats import Stats
from bench.records.arrays import concat_records
from bench.records.board import SPEED_DTYPE, STATUS_DTYPE, speed_records, status_records
from bench.records.events import EVENT_DTYPE, NO_EVENTS, EventKind, concat_events, make_events
from bench.records.model import NO_MODEL_ROWS
from bench.records.results import ESTIMATE_DTYPE, RESULT_DTYPE
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
_NO_ACC = np.zeros((0, 3))
_NO_USABLE = np.zeros((0, 3), bool)


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


def new_estimator(config: Config) -> EstimatorLike:
    """The bench's estimator (its kernels compiled or loaded from numba's cache now: numba is
    imported here, not with this module)."""
    from bench.fusion.estimator import Estimator

    return Estimator(config)


@dataclass(slots=True)
class Referenced:
    """A step through :meth:`Pipeline.reference`: ``out.results`` without the estimator's
    columns, ``out.events`` not yet joined; what :meth:`Pipeline.estimate` completes."""

    out: StepOutput
    acc: np.ndarray  # (N, 3) calibrated m/s^2 of every channel
    usable: np.ndarray  # (N, 3) present and status OK
    votes: np.ndarray  # VOTE_FAIL and INVALID events of these samples
    parts: list[np.ndarray]  # the step's event parts; the fusion's go in at index 1


class Pipeline:
    def __init__(
        self, config: Config, *, estimator: EstimatorLike | None = None, later: bool = False
    ) -> None:
        """``estimator``: a stand-in (default: the bench's, built now); ``later``: built on
        first use instead (a replay builds it while its first steps are referenced)."""
        self.config = config
        self.assembler = Assembler(config.sample_rate_hz)
        self._estimator = estimator if estimator is not None or later else new_estimator(config)
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

    @property
    def estimator(self) -> EstimatorLike:
        if self._estimator is None:
            self._estimator = new_estimator(self.config)
        return self._estimator

    @estimator.setter
    def estimator(self, estimator: EstimatorLike) -> None:
        self._estimator = estimator

    # -- stream ----------------------------------------------------------------------------
    def process(self, batch: SourceBatch) -> StepOutput:
        return self.estimate(self.reference(batch))

    def finish(self) -> StepOutput:
        return self.estimate(self.reference_finish())

    def reference(self, batch: SourceBatch) -> Referenced:
        """The first stage of a step: decode, assemble, the reference method."""
        frames = batch.frames
        dec = decode_batch(frames, self.config.base_id)
        seq0 = self.seq
        self.seq += len(frames)
        self.stats.count_frames(dec.can_id)
        samples, events = self.assembler.push(frames["t"], dec, seq0)
        return self._reference(samples, events, frames, dec, seq0, batch)

    def reference_finish(self) -> Referenced:
        """The first stage of the final flush (the samples the assembler still holds)."""
        samples, events = self.assembler.finish()
        return self._reference(samples, events, _NO_FRAMES, EMPTY_DECODED, self.seq, None)

    def estimate(self, step: Referenced) -> StepOutput:
        """The second stage of a step: the estimator's columns and events, in the order of
        the first stage's steps."""
        out = step.out
        est_events = self._estimate(out.results, out.samples, step.acc, step.usable, out.speed)
        step.parts[1] = concat_events([step.votes, est_events])
        out.events = concat_events(step.parts)
        self.stats.count_events(out.events)
        self.stats.count_results(out.results)
        return out

    def compute(self, samples: np.ndarray, speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fusion of emitted samples: reference method + estimator; results and events."""
        results, acc, ok, votes = self._fuse(samples)
        return results, concat_events([votes, self._estimate(results, samples, acc, ok, speed)])

    # -- internals -------------------------------------------------------------------------
    def _reference(
        self,
        samples: np.ndarray,
        events: np.ndarray,
        frames: np.ndarray,
        dec: DecodedBatch,
        seq0: int,
        batch: SourceBatch | None,
    ) -> Referenced:
        t = frames["t"]
        status = status_records(t, dec, seq0)
        speed = speed_records(t, dec, seq0)
        results, acc, ok, votes = self._fuse(samples)
        parts = [events, NO_EVENTS]  # the fusion's events: Pipeline.estimate
        if batch is not None and (batch.link_errors or batch.notices):
            parts.append(self._source_events(batch))
        if len(status):
            parts.append(self._state_events(status))
            self.last_status = status[-1]
            self.stats.status_frames += len(status)
        if len(speed):
            self.last_speed = speed[-1]
            self.stats.speed_frames += len(speed)
        self.stats.count_channel_frames(t, dec)
        out = StepOutput(
            frames, dec.outcome, seq0, samples, results, NO_EVENTS, status, speed, batch
        )
        return Referenced(out, acc, ok, votes, parts)

    def _fuse(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The reference method's rows of emitted samples (the estimator's columns unwritten),
        the calibrated accelerations, which are usable, and the vote events."""
        if len(samples) == 0:
            return _NO_RESULTS, _NO_ACC, _NO_USABLE, NO_EVENTS
        if self.first_ticks is None:
            self.first_ticks = int(samples["ticks"][0])
        res = np.empty(len(samples), dtype=RESULT_DTYPE)  # every field is written here or
        _FROM_SAMPLE.copy(res, samples)  # by the estimator's stage
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
        votes = self._vote_events(samples["t"], samples["n"], ref.votes)
        return res, acc, ok, votes

    def _estimate(
        self,
        results: np.ndarray,
        samples: np.ndarray,
        acc: np.ndarray,
        ok: np.ndarray,
        speed: np.ndarray,
    ) -> np.ndarray:
        """The estimator's columns written into ``results``; its events."""
        if len(samples) == 0:
            if len(speed) == 0:  # nothing to fuse and nothing for the estimator to keep
                return NO_EVENTS
            _, est_events = self.estimator.push(NO_SAMPLES, _NO_ACC, _NO_USABLE, speed)
            return est_events
        est, est_events = self.estimator.push(samples, acc, ok, speed)
        _FROM_ESTIMATE.copy(results, est)
        return est_events

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
