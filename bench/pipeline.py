"""The pipeline: source batches in, samples, results and events out. One for live and replay.

decode (protocol.batch) -> assemble (bench.assembly) -> reference fusion + estimator.
Stateful across batches, and its output does not depend on how the stream is batched,
so a live run and the replay of its log give the same rows bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bench.assembly import SAMPLE_DTYPE, Assembler, usable
from bench.config import Config
from bench.events import EVENT_DTYPE, EventKind, concat_events, make_events
from bench.fusion.estimator import Estimator
from bench.fusion.reference import fuse
from bench.records import SPEED_DTYPE, STATUS_DTYPE, speed_records, status_records
from bench.results import RESULT_DTYPE
from bench.stats import Stats
from devices.base import SourceBatch
from protocol.batch import DecodedBatch, decode_batch
from protocol.frames import empty_frames

_NOTICE_KINDS = {
    "parse_error": EventKind.PARSE_ERROR,
    "truncated": EventKind.PARSE_ERROR,
    "disconnect": EventKind.DISCONNECT,
    "reconnect": EventKind.RECONNECT,
}


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


class Pipeline:
    def __init__(self, config: Config) -> None:
        self.config = config
        self.assembler = Assembler(config.sample_rate_hz)
        self.estimator = Estimator(config)
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
        out = self._fuse(samples, events, frames, dec, seq0, batch)
        return out

    def finish(self) -> StepOutput:
        samples, events = self.assembler.finish()
        return self._fuse(
            samples, events, empty_frames(), decode_batch(empty_frames()), self.seq, None
        )

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
        status = status_records(frames["t"], dec, seq0)
        speed = speed_records(frames["t"], dec, seq0)
        results, fusion_events = self.compute(samples, speed)
        parts = [events, fusion_events]
        if batch is not None:
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
        self._count_channel_frames(frames, dec)
        return StepOutput(
            frames, dec.outcome, seq0, samples, results, all_events, status, speed, batch
        )

    def compute(self, samples: np.ndarray, speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fusion of emitted samples: reference method + estimator."""
        res = np.zeros(len(samples), dtype=RESULT_DTYPE)
        if len(samples) == 0:
            est, est_events = self.estimator.push(
                samples, np.zeros((0, 3)), np.zeros((0, 3), bool), speed
            )
            return res, est_events
        if self.first_ticks is None:
            self.first_ticks = int(samples["ticks"][0])
        for name in ("n", "seq", "ticks", "t", "code", "status", "present"):
            res[name] = samples[name]
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
        for name in est.dtype.names:
            res[name] = est[name]
        return res, concat_events([self._vote_events(res), est_events])

    def _vote_events(self, res: np.ndarray) -> np.ndarray:
        """A VOTE_FAIL event whenever the set of failed votes changes to a non-empty one."""
        mask = (~res["votes"]).astype(np.int64) @ np.array([1, 2, 4])
        prev = np.concatenate(([self._last_fail_mask], mask[:-1]))
        self._last_fail_mask = int(mask[-1])
        change = (mask != prev) & (mask != 0)
        parts = [
            make_events(EventKind.VOTE_FAIL, res["t"][change], 0, res["n"][change], mask[change])
        ]
        into_invalid = change & (mask == 7)
        parts.append(
            make_events(EventKind.INVALID, res["t"][into_invalid], 0, res["n"][into_invalid])
        )
        return concat_events(parts)

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
                parts.append(make_events(kind, notice.t))
        return concat_events(parts)

    def _count_channel_frames(self, frames: np.ndarray, dec: DecodedBatch) -> None:
        good = (dec.channel > 0) & dec.ok
        if not good.any():
            return
        for ch in range(3):
            sel = good & (dec.channel == ch + 1)
            k = int(np.count_nonzero(sel))
            if k:
                cs = self.stats.channels[ch]
                times = frames["t"][sel]
                if cs.frames == 0:
                    cs.first_t = float(times[0])
                cs.last_t = float(times[-1])
                cs.frames += k
