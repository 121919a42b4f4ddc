"""The bench's topics as MCAP messages: one ``write_*`` per topic, onto an :class:`McapFile`.

Also the file's "run" and "config" metadata records, which the live sink and the emulator's
file writer both write.
"""

from __future__ import annotations

import base64
import json
import platform
import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bench import __version__
from bench.config import Config
from bench.mcaplog import schemas as S
from bench.mcaplog.file import LIBRARY, McapFile, utc_now
from bench.pipeline.stats import Stats
from bench.records.events import EVENT_DTYPE, EventKind, describe, severity
from protocol.batch import decode_batch
from protocol.layout import DEFAULT_BASE, SPEED_REF_ID
from protocol.records import FLAG_UART, LinkError

_T_MAX_S = 1.8e10
"""Receive times beyond this (year 2540) or negative cannot be a log_time: substituted."""

REPLAY_LANE = 1
"""Chunk lane of the topics a replay reads (MessageEncoder.REPLAY_TOPICS); 0 = the rest."""


class MessageEncoder:
    """Turns pipeline output into messages on the bench's topics of one :class:`McapFile`.

    Owns the log_time policy: receive time in ns; a NaN/negative/absurd time gets a
    monotonic substitute (the latest log_time so far, or the bench clock if later) and is
    counted in ``substituted`` (reported in the ``summary`` metadata record).
    The replay inputs (:attr:`REPLAY_TOPICS`) get chunks of their own (``REPLAY_LANE``).
    """

    REPLAY_TOPICS = frozenset({S.FRAME_TOPIC, S.LINK_ERROR_TOPIC, S.NOTICE_TOPIC})
    """What a replay reads; link errors and notices share the frames' chunks so that their
    place between the frames (the live batching) is kept."""

    def __init__(
        self,
        mf: McapFile,
        base_id: int = DEFAULT_BASE,
        extra_topics: Sequence[S.TopicSpec] = (),
        result_columns: Sequence[S.Column] = S.RESULT_COLUMNS,
    ) -> None:
        self.mf = mf
        self.base_id = base_id
        self.cid: dict[str, int] = {}
        self.result_columns = result_columns  # more: the rows carry the smoother's columns
        topics = S.TOPICS
        if result_columns is not S.RESULT_COLUMNS:
            mine = S.result_topic(result_columns)
            topics = tuple(mine if t.topic == S.RESULT_TOPIC else t for t in S.TOPICS)
        for spec in (*topics, *extra_topics):
            sid = mf.add_schema(spec.schema_name, spec.schema_encoding, spec.schema_data)
            self.cid[spec.topic] = mf.add_channel(
                spec.topic,
                spec.message_encoding,
                sid,
                {"description": spec.description},
                lane=REPLAY_LANE if spec.topic in self.REPLAY_TOPICS else 0,
            )
        self.last_ns = 0
        self.substituted = 0
        self.frames = 0
        self._seq: Counter[int] = Counter()
        self._events: dict[tuple[int, int, int], tuple[str, str | None, int, str]] = {}

    # -- time ------------------------------------------------------------------------------
    def log_ns(self, t: np.ndarray, fallback_ns: int) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        ok = np.isfinite(t) & (t >= 0) & (t < _T_MAX_S)
        ns = np.zeros(len(t), dtype=np.uint64)
        ns[ok] = np.rint(t[ok] * 1e9).astype(np.uint64)
        bad = len(t) - int(np.count_nonzero(ok))
        if bad:
            ns[~ok] = max(self.last_ns, fallback_ns)
            self.substituted += bad
        if len(ns):
            self.last_ns = max(self.last_ns, int(ns.max()))
        return ns

    def _next_seq(self, cid: int, n: int) -> np.ndarray:
        start = self._seq[cid]
        self._seq[cid] += n
        return np.arange(start, start + n, dtype=np.int64) & 0xFFFFFFFF

    # -- frames ----------------------------------------------------------------------------
    def frames_records(
        self,
        frames: np.ndarray,
        outcome: np.ndarray | None,
        fallback_ns: int,
        starts: Sequence[int] | np.ndarray = (),
    ) -> np.ndarray:
        n = len(frames)
        rec = np.zeros(n, dtype=S.FRAME_RECORD_DTYPE)
        if n == 0:
            return rec
        if outcome is None or len(outcome) != n:
            outcome = decode_batch(frames, self.base_id).outcome
        ids = frames["id"]
        off = ids.astype(np.int64) - self.base_id
        counted = ((off >= 0) & (off <= 3)) | (ids == SPEED_REF_ID)
        ns = self.log_ns(frames["t"], fallback_ns)
        rec["opcode"] = S.MESSAGE_OPCODE
        rec["length"] = S.FRAME_RECORD_LENGTH
        rec["channel_id"] = self.cid[S.FRAME_TOPIC]
        rec["sequence"] = np.where(counted, frames["data"][:, 0], 0)
        rec["log_time"] = ns
        rec["publish_time"] = ns
        p = rec["payload"]
        for name, value in S.FRAME_PB_CONST.items():
            p[name] = value
        p["t"] = frames["t"]
        p["id"] = ids
        p["dlc"] = frames["dlc"]
        p["flags"] = frames["flags"]
        if len(starts):
            p["flags"][np.asarray(starts, dtype=np.int64)] |= S.FLAG_BATCH_START
        p["outcome"] = np.asarray(outcome, dtype=np.uint8) & 0x7F
        p["uart"] = (frames["flags"] & FLAG_UART) != 0
        p["data"] = frames["data"]
        return rec

    def write_frames(
        self,
        frames: np.ndarray,
        outcome: np.ndarray | None,
        fallback_ns: int,
        starts: Sequence[int] | np.ndarray = (),
    ) -> None:
        """Raw frames; ``starts``: indices of frames that opened a source batch (so a replay
        can reproduce the live batching exactly, see reader.iter_batches)."""
        if len(frames):
            recs = self.frames_records(frames, outcome, fallback_ns, starts)
            self.mf.add_fixed_records(self.cid[S.FRAME_TOPIC], recs)
            self.frames += len(frames)

    # -- JSON topics -----------------------------------------------------------------------
    def _json(
        self,
        topic: str,
        t: np.ndarray,
        payloads: list[bytes],
        fallback_ns: int,
        seq: np.ndarray | None = None,
    ) -> None:
        if not payloads:
            return
        cid = self.cid[topic]
        ns = self.log_ns(t, fallback_ns)
        self.mf.add_messages(
            cid, ns, payloads, self._next_seq(cid, len(payloads)) if seq is None else seq
        )

    def write_link_errors(self, errors: Sequence[LinkError], fallback_ns: int) -> None:
        if not errors:
            return
        payloads = [
            _obj(
                ("t", S.json_text(float(e.t))),
                ("outcome", str(int(e.outcome))),
                ("outcome_name", json.dumps(S.outcome_name(int(e.outcome)))),
                ("raw", json.dumps(base64.b64encode(bytes(e.raw)).decode())),
                ("length", str(len(e.raw))),
                ("detail", json.dumps(e.detail)),
            )
            for e in errors
        ]
        t = np.array([e.t for e in errors], dtype=np.float64)
        self._json(S.LINK_ERROR_TOPIC, t, payloads, fallback_ns)

    def write_notices(self, notices: Sequence[Any], fallback_ns: int) -> None:
        if not notices:
            return
        payloads = [
            _obj(
                ("t", S.json_text(float(n.t))),
                ("kind", json.dumps(n.kind)),
                ("detail", json.dumps(n.detail)),
                ("count", str(int(n.count))),
            )
            for n in notices
        ]
        t = np.array([n.t for n in notices], dtype=np.float64)
        self._json(S.NOTICE_TOPIC, t, payloads, fallback_ns)

    def write_samples(self, samples: np.ndarray, fallback_ns: int) -> None:
        if len(samples):
            payloads = S.encode_rows(samples, S.SAMPLE_COLUMNS)
            self._json(
                S.SAMPLE_TOPIC, samples["t"], payloads, fallback_ns, samples["n"] & 0xFFFFFFFF
            )

    def write_results(self, results: np.ndarray, fallback_ns: int) -> None:
        if len(results):
            payloads = S.encode_rows(results, self.result_columns)
            self._json(
                S.RESULT_TOPIC, results["t"], payloads, fallback_ns, results["n"] & 0xFFFFFFFF
            )

    def write_status(self, status: np.ndarray, fallback_ns: int) -> None:
        if len(status):
            extra = [
                ("state_name", [json.dumps(S.state_name(s)) for s in status["state"].tolist()]),
                (
                    "supply_v",
                    S.tokens(S.Column("supply_v", "supply", None, "float"), _supply_v(status)),
                ),
            ]
            payloads = S.encode_rows(status, S.STATUS_COLUMNS, extra)
            self._json(
                S.STATUS_TOPIC,
                status["t"],
                payloads,
                fallback_ns,
                status["counter"].astype(np.int64),
            )

    def write_speed(self, speed: np.ndarray, fallback_ns: int) -> None:
        if len(speed):
            mps = np.zeros(len(speed), dtype=[("speed_mps", "<f8")])
            mps["speed_mps"] = speed["speed"] / 1000.0
            extra = [
                ("speed_mps", S.tokens(S.Column("speed_mps", "speed_mps", None, "float"), mps))
            ]
            payloads = S.encode_rows(speed, S.SPEED_COLUMNS, extra)
            self._json(
                S.SPEED_TOPIC, speed["t"], payloads, fallback_ns, speed["counter"].astype(np.int64)
            )

    def write_events(
        self, events: np.ndarray, fallback_ns: int, name: str = "bench", text: str | None = None
    ) -> None:
        """Events as foxglove.Log JSON, built from whole columns; the message text comes from
        a cache of :func:`_event_parts` (few distinct kind/channel/value), so describe() runs
        once per distinct event, not per event (a run can log millions of CRC errors)."""
        if len(events) == 0:
            return
        ns = self.log_ns(events["t"], fallback_ns)
        after = "" if text is None else _json_chars(f": {text}")
        extra = "" if text is None else f',"text":"{_json_chars(text)}"'
        who = json.dumps(name)
        payloads = []
        for lt, t, kind, ch, n, value in zip(
            ns.tolist(),
            S.float_tokens(events["t"]),
            events["kind"].tolist(),
            events["channel"].tolist(),
            events["n"].tolist(),
            events["value"].tolist(),
            strict=True,
        ):
            head, tail, level, kind_name = self._event_parts(kind, ch, value)
            sample = "" if tail is None or n < 0 else f" sample {n}"
            payloads.append(
                f'{{"timestamp":{{"sec":{lt // 1_000_000_000},"nsec":{lt % 1_000_000_000}}},'
                f'"level":{level},"message":"{head}{sample}{tail or ""}{after}","name":{who},'
                f'"file":"","line":0,"t":{t},"kind":{kind},"kind_name":{kind_name},'
                f'"channel":{ch},"n":{n},"value":{value}{extra}}}'.encode()
            )
        cid = self.cid[S.EVENT_TOPIC]
        self.mf.add_messages(cid, ns, payloads, self._next_seq(cid, len(payloads)))

    def _event_parts(self, kind: int, channel: int, value: int) -> tuple[str, str | None, int, str]:
        key = (kind, channel, value)
        parts = self._events.get(key)
        if parts is None:
            if len(self._events) >= 4096:  # e.g. many distinct SAMPLES_LOST counts
                self._events.clear()
            parts = self._events[key] = _event_parts(kind, channel, value)
        return parts

    def write_health(self, stats: Stats, t: float, dropped: int, fallback_ns: int) -> None:
        d: dict[str, Any] = {"t": t}
        for name in S.HEALTH_TOTAL_FIELDS:
            d[name] = dropped if name == "dropped_frames" else int(getattr(stats, name))
        d["valid_fraction"] = stats.valid / stats.samples if stats.samples else 0.0
        d["channels"] = [
            {
                "channel": k + 1,
                "rate_hz": c.rate_hz(),
                **{f: int(getattr(c, f)) for f in S.HEALTH_CHANNEL_FIELDS},
            }
            for k, c in enumerate(stats.channels)
        ]
        payload = json.dumps(d, separators=(",", ":")).replace("NaN", "null").encode()
        self._json(S.HEALTH_TOPIC, np.array([t]), [payload], fallback_ns)

    def write_model(self, rows: np.ndarray, fallback_ns: int) -> None:
        """The live model's rows (MODEL_DTYPE); its channel is added with the first."""
        if not len(rows):
            return
        if S.MODEL_TOPIC not in self.cid:
            spec = S.MODEL_TOPIC_SPEC
            sid = self.mf.add_schema(spec.schema_name, spec.schema_encoding, spec.schema_data)
            self.cid[spec.topic] = self.mf.add_channel(
                spec.topic, spec.message_encoding, sid, {"description": spec.description}
            )
        self._json(S.MODEL_TOPIC, rows["t"], S.encode_rows(rows, S.MODEL_COLUMNS), fallback_ns)

    def write_truth(
        self, rows: np.ndarray, columns: Sequence[S.Column], t: np.ndarray, fallback_ns: int
    ) -> None:
        if len(rows):
            self._json(S.TRUTH_TOPIC, t, S.encode_rows(rows, columns), fallback_ns)


def _event_parts(kind: int, channel: int, value: int) -> tuple[str, str | None, int, str]:
    """An event's message (JSON-escaped, no quotes) split where describe() puts its
    " sample N" part: (before, after or None when there is no sample part), then its
    foxglove level and its kind_name token. describe() stays the only renderer: it is
    called with n = -1 and n = 0 and the difference located."""
    probe = np.zeros(2, dtype=EVENT_DTYPE)
    probe["kind"], probe["channel"], probe["value"], probe["n"] = kind, channel, value, (-1, 0)
    try:
        without, with_sample = describe(probe[0]), describe(probe[1])
        kind_name = json.dumps(EventKind(kind).name)
        level = S.LOG_LEVELS.get(severity(kind), 4)
    except ValueError:
        return f"EVENT {kind}", None, 4, json.dumps(str(kind))
    head, found, tail = with_sample.partition(" sample 0")
    if not found or head + tail != without:  # not a plain insertion: never split it
        return _json_chars(without), None, level, kind_name
    return _json_chars(head), _json_chars(tail), level, kind_name


def _json_chars(text: str) -> str:
    """``text`` escaped for a JSON string, without the quotes (escaping is per character,
    so escaped pieces concatenate to the escaped whole)."""
    return json.dumps(text, ensure_ascii=False)[1:-1]


def _obj(*fields: tuple[str, str]) -> bytes:
    """A JSON object from (name, already encoded JSON token) pairs."""
    return ("{" + ",".join(f'"{k}":{v}' for k, v in fields) + "}").encode()


def _supply_v(status: np.ndarray) -> np.ndarray:
    out = np.zeros(len(status), dtype=[("supply", "<f8")])
    out["supply"] = status["supply"] * 0.1
    return out


def config_record(config: Config) -> dict[str, str]:
    """The config as loaded: its TOML text (what replay reads back) plus flat keys to browse."""
    meta = {
        "source": config.source,
        "origin": config.origin,
        "described": config.describe(),
        "toml": config.to_toml(),
        "base_id": f"0x{config.base_id:X}",
    }
    if getattr(config, "path", None):
        meta["path"] = str(config.path)
    meta["sample_rate_hz"] = str(config.sample_rate_hz)
    for k, ch in enumerate(config.channels, start=1):
        meta[f"ch{k}.angle_deg"] = repr(ch.angle_deg)
        meta[f"ch{k}.scale"] = repr(ch.scale)
        meta[f"ch{k}.offset"] = repr(ch.offset)
    meta["g"] = repr(config.g)
    meta["tolerance_permil"] = repr(config.tolerance_permil)
    return meta


def run_record(extra: Mapping[str, str] | None) -> dict[str, str]:
    meta = {
        "format": "acb3-bench-mcap",
        "format_version": S.FORMAT_VERSION,
        "bench_version": __version__,
        "created_utc": utc_now(),
        "writer": LIBRARY,
        "python": platform.python_version(),
        "host": platform.node(),
        "command": " ".join(sys.argv),
    }
    meta.update({str(k): str(v) for k, v in (extra or {}).items()})
    return meta
