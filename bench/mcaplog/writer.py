"""Writing the bench's MCAP files: a small, fast chunked writer, the live-run sink, the emulator.

Why not ``mcap.writer.Writer``: it builds every message record in Python (~120 k msg/s
here), and it has no way to add a pre-built block of records. Raw frames are the bulk of
a file and have a fixed-size encoding (see :mod:`bench.mcaplog.schemas`), so
:class:`McapFile` writes a whole batch of them as one numpy buffer plus one vectorised
MessageIndex. The non-bulk records (header, schemas, channels, metadata, attachments,
summary) are serialised with the ``mcap`` package's own record classes, so the file
layout is the reference implementation's.

Chunk lanes: the replay inputs (raw frames, UART link errors, source notices) are written
into chunks of their own, never mixed with the much bigger derived topics (samples,
results, ...). A replay then decompresses and CRC-checks only those chunks, and a reader
of a derived topic only the others. Frames keep their arrival order (one lane, chunks in
write order); @mcap/core merges the overlapping lanes by log time through the indexes.

Crash safety: the live sink closes the open chunks (and flushes them to the OS) at least
every ``flush_interval_s`` of wall time, so a kill -9 loses at most that much; a clean
close writes the summary section (statistics, chunk/metadata/attachment indexes) and the
footer. An unfinished file is still readable chunk by chunk (:mod:`bench.mcaplog.reader`).
"""

from __future__ import annotations

import atexit
import base64
import contextlib
import itertools
import json
import logging
import math
import platform
import queue
import struct
import sys
import threading
import time
import zlib
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Self

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from bench import __version__
from bench.arrays import concat_records as _concat
from bench.config import Config
from bench.events import EVENT_DTYPE, EventKind, describe, make_events, severity
from bench.mcaplog import schemas as S
from bench.pipeline import StepOutput
from bench.stats import Stats
from devices.base import SourceBatch
from protocol.batch import decode_batch
from protocol.frames import FRAME_DTYPE, frames_from_raw
from protocol.layout import DEFAULT_BASE, SPEED_REF_ID, Outcome
from protocol.records import FLAG_UART, LinkError

log = logging.getLogger("bench.mcaplog")

MAGIC = b"\x89MCAP0\r\n"
LIBRARY = f"gradient-bench/{__version__} bench.mcaplog"
DEFAULT_CHUNK_SIZE = 4 << 20
"""Uncompressed bytes per chunk before it is closed regardless of time (~60 k frames)."""
DEFAULT_FLUSH_INTERVAL_S = 0.5
"""A live chunk is closed and flushed when its first message is this old (wall time)."""
DEFAULT_GROUP_INTERVAL_S = 0.05
"""The live writer encodes the steps that arrive within this long as one group."""
_MAX_NS = (1 << 64) - 1
_T_MAX_S = 1.8e10
"""Receive times beyond this (year 2540) or negative cannot be a log_time: substituted."""
_HEADER_DTYPE = np.dtype(S.MESSAGE_HEADER)
REPLAY_LANE = 1
"""Chunk lane of the topics a replay reads (MessageEncoder.REPLAY_TOPICS); 0 = the rest."""


def _media_type(name: str) -> str:
    suffix = Path(name).suffix.lower()
    return {
        ".toml": "application/toml",
        ".json": "application/json",
        ".csv": "text/csv",
        ".txt": "text/plain",
        ".md": "text/markdown",
        ".log": "text/plain",
        ".dbc": "text/plain",
    }.get(suffix, "application/octet-stream")


def _utc_now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


# ------------------------------------------------------------------------------------------
class McapFile:
    """Append-only chunked MCAP writer (not thread-safe: one owner thread).

    Messages go into the open chunk of their channel's lane (see :meth:`add_channel`);
    :meth:`flush_chunk` compresses the open chunks, writes them with their MessageIndex
    records and flushes the file object; :meth:`maybe_flush` closes only the lanes that
    reached ``chunk_size``. :meth:`finish` writes DataEnd (with the data-section CRC), the
    summary section and the footer. Every OSError propagates: the caller decides what a
    failed disk means.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "zstd",
        library: str = LIBRARY,
        profile: str = S.PROFILE,
    ) -> None:
        if compression not in ("zstd", "lz4", ""):
            raise ValueError(f"unsupported compression {compression!r}")
        self.path = Path(path)
        self.chunk_size = chunk_size
        self.compression = compression
        self._compress = _compressor(compression)
        self._fh = open(self.path, "wb")  # noqa: SIM115 - owned until finish()/abort()
        self.position = 0
        self._crc = 0
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._counts: Counter[int] = Counter()
        self._t_min: int | None = None
        self._t_max = 0
        self._lanes: dict[int, _OpenChunk] = {}  # lane -> its open chunk
        self._lane_of: dict[int, _OpenChunk] = {}  # channel id -> its lane's open chunk
        self.closed = False
        self._write(MAGIC)
        self._record(Header(profile=profile, library=library))

    # -- low level -------------------------------------------------------------------------
    def _write(self, data: bytes | memoryview) -> None:
        self._fh.write(data)
        self._crc = zlib.crc32(data, self._crc)
        self.position += len(data)

    def _record(self, record: McapRecord) -> tuple[int, int]:
        """Serialise one record with the mcap package; returns (offset, length)."""
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        offset = self.position
        self._write(data)
        return offset, len(data)

    @property
    def pending_messages(self) -> int:
        """Messages in the open chunks (not yet written)."""
        return sum(c.messages for c in self._lanes.values())

    def written(self, channel_id: int) -> int:
        """Messages of one channel in chunks written (and flushed) so far."""
        return self._counts[channel_id]

    # -- definitions -----------------------------------------------------------------------
    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._record(schema)
        return schema.id

    def add_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
        *,
        lane: int = 0,
    ) -> int:
        """A channel whose messages go into the chunks of ``lane``: channels of different
        lanes never share a chunk, so a reader of one lane's channels skips the others'."""
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=dict(metadata or {}),
        )
        self._channels.append(channel)
        self._lane_of[channel.id] = self._lanes.setdefault(lane, _OpenChunk())
        self._record(channel)
        return channel.id

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        offset, length = self._record(
            Metadata(name=name, metadata={str(k): str(v) for k, v in data.items()})
        )
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))

    def add_attachment(
        self, name: str, data: bytes, media_type: str = "", log_time: int = 0
    ) -> None:
        media_type = media_type or _media_type(name)
        att = Attachment(
            create_time=log_time,
            log_time=log_time,
            name=name,
            media_type=media_type,
            data=bytes(data),
        )
        offset, length = self._record(att)
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=offset,
                length=length,
                log_time=log_time,
                create_time=log_time,
                data_size=len(att.data),
                name=name,
                media_type=media_type,
            )
        )

    # -- messages --------------------------------------------------------------------------
    def _add_block(
        self, channel_id: int, block: bytes, log_times: np.ndarray, rel_offsets: np.ndarray
    ) -> None:
        if len(log_times):
            chunk = self._lane_of.get(channel_id)
            if chunk is None:
                raise ValueError(f"message on unknown channel {channel_id}")
            chunk.add(channel_id, block, log_times, rel_offsets)

    def add_fixed_records(self, channel_id: int, records: np.ndarray) -> None:
        """Append complete, already filled Message records of one fixed size (a structured
        array whose dtype starts with schemas.MESSAGE_HEADER)."""
        size = records.dtype.itemsize
        self._add_block(
            channel_id,
            records.tobytes(),
            records["log_time"],
            np.arange(len(records), dtype=np.uint64) * np.uint64(size),
        )

    def add_messages(
        self,
        channel_id: int,
        log_times: np.ndarray,
        payloads: Sequence[bytes],
        sequences: Sequence[int] | np.ndarray,
    ) -> None:
        """Append variable-size messages (JSON) to the open chunk: the record headers are
        filled as one numpy array and interleaved with the payloads in one join."""
        n = len(payloads)
        if not n:
            return
        lens = np.fromiter(map(len, payloads), dtype=np.uint64, count=n)
        heads = np.empty(n, dtype=_HEADER_DTYPE)
        heads["opcode"] = S.MESSAGE_OPCODE
        heads["length"] = lens + np.uint64(S.MESSAGE_HEADER_SIZE - 9)
        heads["channel_id"] = channel_id
        heads["sequence"] = np.asarray(sequences, dtype=np.int64) & 0xFFFFFFFF
        heads["log_time"] = log_times
        heads["publish_time"] = log_times
        raw = heads.tobytes()
        size = S.MESSAGE_HEADER_SIZE
        headers = [raw[i : i + size] for i in range(0, n * size, size)]
        block = b"".join(itertools.chain.from_iterable(zip(headers, payloads, strict=True)))
        sizes = lens + np.uint64(size)
        self._add_block(
            channel_id, block, np.asarray(log_times, dtype=np.uint64), np.cumsum(sizes) - sizes
        )

    def maybe_flush(self) -> int:
        """Close the open chunks that reached ``chunk_size``; returns messages written."""
        return sum(self._write_chunk(c) for c in self._open_chunks() if c.length >= self.chunk_size)

    def flush_chunk(self) -> int:
        """Close every open chunk: compress, write it and its MessageIndex records, flush
        the file object. Returns the number of messages written (0 if none was open)."""
        return sum(self._write_chunk(c) for c in self._open_chunks())

    def _open_chunks(self) -> list[_OpenChunk]:
        """Non-empty open chunks, earliest first (chunk order follows log time)."""
        return sorted((c for c in self._lanes.values() if c.messages), key=lambda c: c.start)

    def _write_chunk(self, chunk: _OpenChunk) -> int:
        """Write one open chunk and its MessageIndex records; reset it."""
        count = chunk.messages
        data = b"".join(chunk.parts)
        compressed = self._compress(data)
        name = self.compression.encode()
        head = struct.pack(
            "<BQQQQI",
            Opcode.CHUNK,
            8 + 8 + 8 + 4 + 4 + len(name) + 8 + len(compressed),
            chunk.start,
            chunk.end,
            len(data),
            zlib.crc32(data),
        )
        head += struct.pack("<I", len(name)) + name + struct.pack("<Q", len(compressed))
        chunk_start = self.position
        self._write(head)
        self._write(compressed)
        chunk_length = self.position - chunk_start
        index_start = self.position
        offsets: dict[int, int] = {}
        blocks = []
        pos = index_start
        for cid in sorted(chunk.index):
            parts = chunk.index[cid]
            body = (np.concatenate(parts) if len(parts) > 1 else parts[0]).tobytes()
            blocks.append(
                struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 2 + 4 + len(body), cid, len(body)) + body
            )
            offsets[cid] = pos
            pos += len(blocks[-1])
        self._write(b"".join(blocks))
        self._fh.flush()  # first: a chunk the OS refused is not counted as written
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=chunk.start,
                message_end_time=chunk.end,
                chunk_start_offset=chunk_start,
                chunk_length=chunk_length,
                message_index_offsets=offsets,
                message_index_length=self.position - index_start,
                compression=self.compression,
                compressed_size=len(compressed),
                uncompressed_size=len(data),
            )
        )
        self._counts.update(chunk.counts)
        self._t_min = chunk.start if self._t_min is None else min(self._t_min, chunk.start)
        self._t_max = max(self._t_max, chunk.end)
        chunk.reset()
        return count

    def flush_io(self) -> None:
        self._fh.flush()

    # -- end -------------------------------------------------------------------------------
    def finish(self) -> None:
        """Write the last chunk, DataEnd, summary, summary offsets, footer and magic; close."""
        self.flush_chunk()
        self._record(DataEnd(data_section_crc=self._crc))
        summary_start = self.position
        builder = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: int, records: Iterable[McapRecord]) -> None:
            start = builder.count
            for rec in records:
                rec.write(builder)
            if builder.count > start:
                offsets.append(
                    SummaryOffset(
                        group_opcode=opcode,
                        group_start=summary_start + start,
                        group_length=builder.count - start,
                    )
                )

        stats = Statistics(
            message_count=sum(self._counts.values()),
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=len(self._attachment_indexes),
            metadata_count=len(self._metadata_indexes),
            chunk_count=len(self._chunk_indexes),
            message_start_time=self._t_min or 0,
            message_end_time=self._t_max,
            channel_message_counts={c.id: self._counts[c.id] for c in self._channels},
        )
        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + builder.count
        for off in offsets:
            off.write(builder)
        summary = builder.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(
            struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc
        )
        self._write(summary)
        self._record(
            Footer(
                summary_start=summary_start,
                summary_offset_start=summary_offset_start,
                summary_crc=crc,
            )
        )
        self._write(MAGIC)
        self._fh.close()
        self.closed = True

    def abort(self) -> None:
        """Close the file without a summary (after a write error): what is there stays
        readable up to the last complete chunk."""
        self.closed = True
        with contextlib.suppress(OSError):
            self._fh.close()


class _OpenChunk:
    """The records of one lane's open chunk, with its MessageIndex entries and time span."""

    __slots__ = ("counts", "end", "index", "length", "messages", "parts", "start")

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.parts: list[bytes] = []
        self.length = 0
        self.index: dict[int, list[np.ndarray]] = {}  # channel -> (log_time, offset) rows
        self.counts: dict[int, int] = {}
        self.messages = 0
        self.start = _MAX_NS
        self.end = 0

    def add(
        self, channel_id: int, block: bytes, log_times: np.ndarray, rel_offsets: np.ndarray
    ) -> None:
        n = len(log_times)
        entries = np.empty((n, 2), dtype="<u8")
        entries[:, 0] = log_times
        entries[:, 1] = rel_offsets
        entries[:, 1] += self.length
        self.index.setdefault(channel_id, []).append(entries)
        self.counts[channel_id] = self.counts.get(channel_id, 0) + n
        self.messages += n
        self.parts.append(block)
        self.length += len(block)
        self.start = min(self.start, int(log_times.min()))
        self.end = max(self.end, int(log_times.max()))


def _compressor(name: str):  # type: ignore[no-untyped-def]
    if name == "zstd":
        import zstandard

        cctx = zstandard.ZstdCompressor(level=1)  # ~2x level 3's speed, same ratio here
        return cctx.compress
    if name == "lz4":
        import lz4.frame

        return lz4.frame.compress
    return bytes


# ------------------------------------------------------------------------------------------
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
        self, mf: McapFile, base_id: int = DEFAULT_BASE, extra_topics: Sequence[S.TopicSpec] = ()
    ) -> None:
        self.mf = mf
        self.base_id = base_id
        self.cid: dict[str, int] = {}
        for spec in (*S.TOPICS, *extra_topics):
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
            payloads = S.encode_rows(results, S.RESULT_COLUMNS)
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

    def write_truth(
        self, rows: np.ndarray, columns: Sequence[S.Column], t: np.ndarray, fallback_ns: int
    ) -> None:
        if len(rows):
            self._json(S.TRUTH_TOPIC, t, S.encode_rows(rows, columns), fallback_ns)


_MAX_GROUP = 512
"""Most queued steps the writer thread merges into one encoding pass."""


def _outcome(step: StepOutput, base_id: int) -> np.ndarray:
    if len(step.outcome) == len(step.frames):
        return step.outcome
    return decode_batch(step.frames, base_id).outcome


def _merge_steps(
    items: list[tuple[StepOutput, int]], base_id: int
) -> tuple[StepOutput, int, np.ndarray]:
    """Consecutive steps as one (arrays concatenated in order), the first step's enqueue
    time, and the index of each step's first frame (its source batch start)."""
    steps = [s for s, _ in items]
    sizes = np.array([len(s.frames) for s in steps], dtype=np.int64)
    starts = (np.cumsum(sizes) - sizes)[sizes > 0]
    if len(steps) == 1:
        return steps[0], items[0][1], starts
    link_errors = [e for s in steps if s.batch is not None for e in s.batch.link_errors]
    notices = [n for s in steps if s.batch is not None for n in s.batch.notices]
    cat = lambda name: _concat([getattr(s, name) for s in steps])  # noqa: E731
    frames = cat("frames")
    merged = StepOutput(
        frames=frames,
        outcome=_concat([_outcome(s, base_id) for s in steps]),
        seq0=steps[0].seq0,
        samples=cat("samples"),
        results=cat("results"),
        events=cat("events"),
        status=cat("status"),
        speed=cat("speed"),
        batch=SourceBatch(frames, link_errors, notices),
    )
    return merged, items[0][1], starts


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


def _config_metadata(config: Config) -> dict[str, str]:
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


def _run_metadata(extra: Mapping[str, str] | None) -> dict[str, str]:
    meta = {
        "format": "acb3-bench-mcap",
        "format_version": S.FORMAT_VERSION,
        "bench_version": __version__,
        "created_utc": _utc_now(),
        "writer": LIBRARY,
        "python": platform.python_version(),
        "host": platform.node(),
        "command": " ".join(sys.argv),
    }
    meta.update({str(k): str(v) for k, v in (extra or {}).items()})
    return meta


# ------------------------------------------------------------------------------------------
_STOP = object()


class QueuedSink:
    """The caller's side of a live MCAP sink: a bounded queue that never blocks the
    processing thread (a full queue drops the step and counts its frames in ``dropped``),
    and the figures for a status line. Subclasses start the thread that empties the queue
    (``_thread``); :meth:`_stop_thread` ends it after what is queued."""

    def __init__(
        self,
        path: str | Path,
        config: Config,
        queue_size: int,
        flush_interval_s: float,
        group_interval_s: float,
    ) -> None:
        self.path = Path(path)
        self.config = config
        self.flush_interval_s = flush_interval_s
        self.group_interval_s = group_interval_s
        self.error: str | None = None
        self.errors = 0
        self.frames_lost = 0
        self.frames_logged = 0
        self.bytes_written = 0
        self.dropped = 0
        self.dropped_steps = 0
        self._closed = False
        self._queue: queue.Queue[Any] = queue.Queue(maxsize=queue_size)
        self._thread: threading.Thread | None = None

    def write(self, step: StepOutput) -> None:
        if self._closed:  # a write after close() is a caller bug; count it, do not hang
            self.dropped += len(step.frames)
            return
        try:
            self._queue.put_nowait((step, time.time_ns()))
        except queue.Full:
            self.dropped += len(step.frames)
            self.dropped_steps += 1
            if self.dropped_steps == 1:
                log.warning("MCAP log %s: writer queue full, dropping frames (counted)", self.path)

    def mark(self, t: float, text: str) -> None:
        if self._closed:
            return
        try:
            self._queue.put_nowait(("mark", float(t), str(text), time.time_ns()))
        except queue.Full:
            self.dropped_steps += 1
            log.warning("MCAP log %s: queue full, operator mark %r not logged", self.path, text)

    def _stop_thread(self) -> bool:
        """Mark closed, queue the stop after everything queued and wait for the thread;
        False when already closed (close() is idempotent)."""
        if self._closed:
            return False
        self._closed = True
        with contextlib.suppress(Exception):
            atexit.unregister(self.close)
        thread = self._thread
        while thread is not None and thread.is_alive():
            try:
                self._queue.put(_STOP, timeout=0.2)
                break
            except queue.Full:
                continue
        if thread is not None and thread.ident is not None:  # never started when not threaded
            thread.join()
        return True

    def _drain(self, items: list[Any]) -> list[Any]:
        """``items`` plus whatever else is queued (up to a group's worth; not past a stop)."""
        while items[-1] is not _STOP and len(items) < _MAX_GROUP:
            try:
                items.append(self._queue.get_nowait())
            except queue.Empty:
                break
        return items

    def close(self) -> None:
        self._stop_thread()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def queue_depth(self) -> int:
        return self._queue.qsize()

    def status(self) -> dict[str, Any]:
        """The recording's figures for a status line or the TUI."""
        return {
            "path": str(self.path),
            "frames": self.frames_logged,
            "bytes": self.bytes_written,
            "dropped": self.dropped,
            "lost": self.frames_lost,
            "queue": self.queue_depth,
            "error": self.error,
            "closed": self._closed,
        }


class McapSink(QueuedSink):
    """The MCAP sink of a live run (implements bench.sinks.Sink).

    ``write`` only enqueues (bounded queue; a full queue drops the step and counts its
    frames in ``dropped``, it never blocks acquisition). A writer thread encodes, closes a
    chunk at least every ``flush_interval_s`` and, on :meth:`close`, drains the queue and
    writes the summary. A write error (disk full, unwritable path) never reaches the
    caller: it is kept in ``error``, logged loudly, and everything after it is counted in
    ``frames_lost``. Counters: ``frames_logged`` (frames in flushed chunks),
    ``bytes_written``, ``dropped``, ``frames_lost``, ``errors``.

    ``threaded=False``: no writer thread; the owner calls the writer-side methods itself
    (the writer process of :mod:`bench.mcaplog.writer_process` does).
    """

    def __init__(
        self,
        path: str | Path,
        config: Config,
        metadata: Mapping[str, str] | None = None,
        attachments: Sequence[tuple[str, bytes]] = (),
        *,
        queue_size: int = 10_000,
        flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "zstd",
        health_interval_s: float = 1.0,
        group_interval_s: float = DEFAULT_GROUP_INTERVAL_S,
        threaded: bool = True,
    ) -> None:
        super().__init__(path, config, queue_size, flush_interval_s, group_interval_s)
        self.health_interval_s = health_interval_s
        self._frames_pending = 0
        self._dropped_reported = 0
        self._stats = Stats()
        self._next_health: float | None = None
        self._last_t = math.nan
        self._chunk_opened: float | None = None
        # a merged group stays well inside one chunk (~300 bytes per frame with its results)
        self._group_frames = max(16, chunk_size // 300)
        self._file: McapFile | None = None
        self._enc: MessageEncoder | None = None
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = McapFile(self.path, chunk_size=chunk_size, compression=compression)
            self._file.add_metadata("run", _run_metadata(metadata))
            self._file.add_metadata("config", _config_metadata(config))
            now = time.time_ns()
            for name, data in attachments:
                self._file.add_attachment(name, data, log_time=now)
            self._enc = MessageEncoder(self._file, config.base_id)
            self._file.flush_io()
            self.bytes_written = self._file.position
        except OSError as exc:
            self._fail(exc)
        if threaded:  # else the owner drives _handle_items/_flush/_finish (writer_process)
            self._thread = threading.Thread(
                target=self._run, name=f"mcap-writer:{self.path.name}", daemon=True
            )
            self._thread.start()
            atexit.register(self.close)

    def close(self) -> None:
        """Drain the queue, write the summary and close the file (idempotent)."""
        self._stop_thread()

    # -- writer thread ---------------------------------------------------------------------
    def _fail(self, exc: BaseException) -> None:
        self.errors += 1
        if self.error is None:
            reason = (
                exc.strerror
                if isinstance(exc, OSError) and exc.strerror
                else str(exc) or type(exc).__name__
            )
            self.error = f"{self.path}: {reason}"
            log.error(
                "MCAP log %s FAILED: %s -- nothing more is logged to it (frames counted as lost)",
                self.path,
                reason,
            )
        if self._file is not None:
            self._settle()  # a lane written before the failure is logged, not lost
            self.frames_lost += self._frames_pending
            self._frames_pending = 0
            self._file.abort()
            self._file = None
            self._enc = None

    def _run(self) -> None:
        while True:
            items, since = self._collect()
            stop = bool(items) and items[-1] is _STOP
            if stop:
                items.pop()
            try:
                self._handle_items(items, since)
            except Exception as exc:
                self._fail(exc)
            if stop:
                break
            if (
                self._chunk_opened is not None
                and time.monotonic() - self._chunk_opened >= self.flush_interval_s
            ):
                self._flush()
        self._finish()

    def _collect(self) -> tuple[list[Any], float]:
        """The next group of queued items, and when its first one was taken.

        After the first item the writer sleeps ``group_interval_s`` (never past the chunk's
        flush deadline) and then takes everything queued: the steps are encoded as one
        group, so the per-step fixed costs (numpy calls on arrays of a few rows, ~400 steps
        a second at 1 kHz) are paid ~20 times a second, in short bursts, instead of holding
        the GIL for every step. Under a backlog it does not sleep.
        """
        deadline = None
        if self._chunk_opened is not None:
            deadline = self._chunk_opened + self.flush_interval_s
        try:
            timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
            items = [self._queue.get(timeout=timeout)]
        except queue.Empty:
            return [], time.monotonic()
        since = time.monotonic()
        if items[0] is not _STOP and self._queue.qsize() < _MAX_GROUP:
            until = since + min(self.group_interval_s, self.flush_interval_s)
            wait = (until if deadline is None else min(until, deadline)) - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        return self._drain(items), since

    def _handle_items(self, items: list[Any], since: float) -> None:
        """Marks in order; each run of consecutive steps merged (see _handle_run).
        ``since``: when the writer took the first of them (the chunk's age counts from it)."""
        run: list[tuple[StepOutput, int]] = []
        for item in items:
            if item[0] == "mark":
                self._handle_run(run, since)
                run = []
                _, t, text, wall = item
                if self._enc is not None:
                    marks = make_events(EventKind.MARK, t)
                    try:
                        self._enc.write_events(marks, wall, name="operator", text=text)
                    except Exception as exc:
                        self._fail(exc)
                    self._opened(since)
            else:
                run.append(item)
        self._handle_run(run, since)

    def _handle_run(self, run: list[tuple[StepOutput, int]], since: float) -> None:
        """Consecutive steps, merged into as few encoding passes as the ~1 Hz health
        snapshots allow (a snapshot must see the counters as of its own step)."""
        start = 0
        frames = 0
        last_t = self._last_t
        for i, (step, wall) in enumerate(run):
            t = step.frames["t"]
            frames += len(t)
            finite = t[np.isfinite(t)] if len(t) else t
            if len(finite):
                last_t = float(finite[-1])
            clock = last_t if math.isfinite(last_t) else wall / 1e9
            if len(t) and self._next_health is None:
                self._next_health = clock + self.health_interval_s
            due = len(t) and self._next_health is not None and clock >= self._next_health
            if due or frames >= self._group_frames or i == len(run) - 1:
                group = run[start : i + 1]
                try:
                    self._handle(*_merge_steps(group, self.config.base_id), since)
                except Exception as exc:  # the file failed; the rest is counted as lost
                    self._fail(exc)
                start = i + 1
                frames = 0

    def _handle(self, step: StepOutput, wall: int, starts: np.ndarray, since: float) -> None:
        n = len(step.frames)
        self._account(step)
        if self._enc is None:
            self.frames_lost += n
            return
        enc = self._enc
        self._frames_pending += n  # counted before writing: a failure below moves them to lost
        if self.dropped > self._dropped_reported:
            delta = self.dropped - self._dropped_reported
            self._dropped_reported = self.dropped
            t = float(step.frames["t"][0]) if n else self._last_t
            enc.write_events(make_events(EventKind.DROPPED, t, value=delta), wall, name="logger")
        enc.write_frames(step.frames, step.outcome, wall, starts)
        if step.batch is not None:
            enc.write_link_errors(step.batch.link_errors, wall)
            enc.write_notices(step.batch.notices, wall)
        enc.write_samples(step.samples, wall)
        enc.write_results(step.results, wall)
        enc.write_status(step.status, wall)
        enc.write_speed(step.speed, wall)
        enc.write_events(step.events, wall)
        self._health(step, wall)
        if self._file is not None and self._file.pending_messages:
            self._opened(since)
            if self._file.maybe_flush():
                self._flushed()

    def _opened(self, since: float) -> None:
        if self._chunk_opened is None:
            self._chunk_opened = since

    def _flushed(self) -> None:
        """After chunks were written: frames no longer pending in the file are logged; the
        flush timer restarts only when no chunk is open (lanes are closed independently)."""
        mf = self._file
        if mf is None or not mf.pending_messages:
            self._chunk_opened = None
        self._settle()
        if mf is not None:
            self.bytes_written = mf.position

    def _settle(self) -> None:
        """Move the frames whose chunk was written (and flushed) from pending to logged."""
        if self._file is None or self._enc is None:
            return
        written = self._file.written(self._enc.cid[S.FRAME_TOPIC])
        self._frames_pending -= written - self.frames_logged
        self.frames_logged = written

    def _flush(self) -> None:
        if self._file is None:
            self._chunk_opened = None
            return
        try:
            self._file.flush_chunk()
            self._flushed()
        except Exception as exc:
            self._fail(exc)

    def _account(self, step: StepOutput) -> None:
        st = self._stats
        frames = step.frames
        st.count_frames(frames["id"])
        st.count_events(step.events)
        st.count_results(step.results)
        st.status_frames += len(step.status)
        st.speed_frames += len(step.speed)
        if len(frames) and len(step.outcome) == len(frames):
            ids = frames["id"].astype(np.int64)
            ch = ids - self.config.base_id
            good = (step.outcome == Outcome.OK) & (ch >= 1) & (ch <= 3) & (ids != SPEED_REF_ID)
            for k in range(3):
                sel = good & (ch == k + 1)
                count = int(np.count_nonzero(sel))
                if count:
                    cs = st.channels[k]
                    times = frames["t"][sel]
                    if cs.frames == 0:
                        cs.first_t = float(times[0])
                    cs.last_t = float(times[-1])
                    cs.frames += count
        finite = frames["t"][np.isfinite(frames["t"])] if len(frames) else frames["t"]
        if len(finite):
            self._last_t = float(finite[-1])

    def _health(self, step: StepOutput, wall: int) -> None:
        if self._enc is None or not len(step.frames):
            return
        clock = self._last_t if math.isfinite(self._last_t) else wall / 1e9
        if self._next_health is None:
            self._next_health = clock + self.health_interval_s
        elif clock >= self._next_health:
            self._enc.write_health(self._stats, clock, self.dropped, wall)
            self._next_health = clock + self.health_interval_s

    def _finish(self) -> None:
        if self._file is None or self._enc is None:
            return
        try:
            wall = time.time_ns()
            if self._stats.frames:
                clock = self._last_t if math.isfinite(self._last_t) else wall / 1e9
                self._enc.write_health(self._stats, clock, self.dropped, wall)
            self._file.flush_chunk()
            self._flushed()
            self._file.add_metadata("summary", self.summary())
            self._file.finish()
            self.bytes_written = self._file.position
        except Exception as exc:
            self._fail(exc)

    def summary(self) -> dict[str, str]:
        """End-of-run counters, written as the ``summary`` metadata record."""
        enc = self._enc
        return {
            "stopped_utc": _utc_now(),
            "frames": str(self._stats.frames),
            "frames_logged": str(self.frames_logged + self._frames_pending),
            "frames_by_id": json.dumps(
                {f"0x{k:03X}": v for k, v in sorted(self._stats.frames_by_id.items())}
            ),
            "dropped_frames": str(self.dropped),
            "frames_lost": str(self.frames_lost),
            "log_errors": str(self.errors),
            "log_time_substituted": str(enc.substituted if enc else 0),
            "stats": json.dumps(self._stats.as_dict()),
        }


# ------------------------------------------------------------------------------------------
def _as_frames(frames: Any) -> np.ndarray:
    if isinstance(frames, np.ndarray) and frames.dtype == FRAME_DTYPE:
        return frames
    if (
        isinstance(frames, np.ndarray)
        and frames.dtype.names
        and set(FRAME_DTYPE.names or ()) <= set(frames.dtype.names)
    ):
        out = np.zeros(len(frames), dtype=FRAME_DTYPE)
        for name in FRAME_DTYPE.names or ():
            out[name] = frames[name]
        return out
    return frames_from_raw(frames)


def _as_table(truth: Any) -> np.ndarray | None:
    """A structured array from a truth table (structured array, dict of columns, or an
    object with a ``to_records``/``as_array`` method); None if it is none of these."""
    if truth is None:
        return None
    if isinstance(truth, np.ndarray) and truth.dtype.names:
        return truth
    for attr in ("as_array", "to_array", "to_records"):
        fn = getattr(truth, attr, None)
        if callable(fn):
            arr = np.asarray(fn())
            return arr if arr.dtype.names else None
    cols = truth if isinstance(truth, Mapping) else getattr(truth, "__dict__", None)
    if not isinstance(cols, Mapping):
        return None
    arrays = {k: np.asarray(v) for k, v in cols.items() if isinstance(v, np.ndarray | list | tuple)}
    arrays = {k: v for k, v in arrays.items() if v.ndim >= 1 and v.dtype.kind in "biuf"}
    if not arrays:
        return None
    n = len(next(iter(arrays.values())))
    arrays = {k: v for k, v in arrays.items() if len(v) == n}
    out = np.zeros(n, dtype=[(k, v.dtype, v.shape[1:]) for k, v in arrays.items()])
    for k, v in arrays.items():
        out[k] = v
    return out


def _time_column(rows: np.ndarray) -> np.ndarray:
    for name in ("t", "time", "time_s"):
        if rows.dtype.names and name in rows.dtype.names and rows.dtype[name].shape == ():
            return rows[name].astype(np.float64)
    return np.full(len(rows), np.nan)


def write_emulation(
    path: str | Path,
    emulation: Any,
    scenario_path: str | Path | None = None,
    *,
    config: Config | None = None,
    metadata: Mapping[str, str] | None = None,
    chunk_size: int = DEFAULT_CHUNK_SIZE,
) -> dict[str, int]:
    """Write an emulator run (``emulation.frames`` and, if present, ``.link_errors`` and
    ``.truth``) straight to MCAP, with the scenario file attached. Synchronous: this is a
    batch job, not an acquisition path. Returns counts (frames, link_errors, truth, bytes).
    """
    frames = _as_frames(emulation.frames)
    link_errors = sorted(
        getattr(emulation, "link_errors", None) or [], key=lambda e: (math.isnan(e.t), e.t)
    )
    truth = _as_table(getattr(emulation, "truth", None))
    truth_cols = S.columns_for(truth.dtype) if truth is not None else []
    base_id = (
        config.base_id if config is not None else int(getattr(emulation, "base_id", DEFAULT_BASE))
    )
    wall = time.time_ns()
    mf = McapFile(path, chunk_size=chunk_size)
    try:
        run = {"source": "emulator", "mode": "emulate"}
        scen_bytes = b""
        if scenario_path is not None:
            sp = Path(scenario_path)
            scen_bytes = sp.read_bytes()
            run["scenario"] = sp.name
        scenario = getattr(emulation, "scenario", None)
        seed = getattr(emulation, "seed", getattr(scenario, "seed", None))
        if seed is not None:
            run["seed"] = str(seed)
        if getattr(scenario, "description", ""):
            run["scenario_description"] = str(scenario.description)
        run.update(metadata or {})
        mf.add_metadata("run", _run_metadata(run))
        if config is not None:
            mf.add_metadata("config", _config_metadata(config))
        if scenario_path is not None:
            mf.add_metadata(
                "scenario",
                {"path": str(scenario_path), "toml": scen_bytes.decode("utf-8", "replace")},
            )
            mf.add_attachment(Path(scenario_path).name, scen_bytes, log_time=wall)
        enc = MessageEncoder(mf, base_id, [S.truth_topic(truth_cols)] if truth is not None else [])
        outcome = decode_batch(frames, base_id).outcome
        le_t = np.array([e.t for e in link_errors], dtype=np.float64)
        le_done = 0
        step = 65536
        for start in range(0, len(frames), step):
            part = frames[start : start + step]
            enc.write_frames(part, outcome[start : start + step], wall)
            last = start + step >= len(frames)
            upto = (
                len(link_errors)
                if last
                else int(np.searchsorted(le_t, part["t"][-1], side="right"))
            )
            if upto > le_done:
                enc.write_link_errors(link_errors[le_done:upto], wall)
                le_done = upto
            mf.maybe_flush()
        if le_done < len(link_errors):
            enc.write_link_errors(link_errors[le_done:], wall)
        if truth is not None:
            t = _time_column(truth)
            for start in range(0, len(truth), step):
                enc.write_truth(
                    truth[start : start + step], truth_cols, t[start : start + step], wall
                )
                mf.maybe_flush()
        mf.flush_chunk()
        ids, counts = np.unique(frames["id"], return_counts=True)
        by_id = dict(zip(ids.tolist(), counts.tolist(), strict=True))
        mf.add_metadata(
            "summary",
            {
                "stopped_utc": _utc_now(),
                "frames": str(len(frames)),
                "frames_logged": str(len(frames)),
                "frames_by_id": json.dumps({f"0x{k:03X}": v for k, v in sorted(by_id.items())}),
                "link_errors": str(len(link_errors)),
                "truth_rows": str(0 if truth is None else len(truth)),
                "log_time_substituted": str(enc.substituted),
            },
        )
        mf.finish()
    except BaseException:
        mf.abort()
        raise
    return {
        "frames": len(frames),
        "link_errors": len(link_errors),
        "truth": 0 if truth is None else len(truth),
        "bytes": mf.position,
    }


__all__ = ["McapFile", "McapSink", "MessageEncoder", "write_emulation"]
