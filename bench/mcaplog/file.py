"""The bench's MCAP file writer: a small, fast chunked writer.

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

An unfinished file is still readable chunk by chunk (:mod:`bench.mcaplog.reader`); a clean
:meth:`McapFile.finish` writes the summary section and the footer.
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import os
import struct
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import BinaryIO

try:
    import fcntl
except ImportError:  # Windows: no advisory locks; a second writer is not detected
    fcntl = None  # type: ignore[assignment]  # checked before each use

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
from bench.mcaplog import schemas as S

MAGIC = b"\x89MCAP0\r\n"

LIBRARY = f"gradient-bench/{__version__} bench.mcaplog"

DEFAULT_CHUNK_SIZE = 4 << 20
"""Uncompressed bytes per chunk before it is closed regardless of time (~60 k frames)."""

_MAX_NS = (1 << 64) - 1

_HEADER_DTYPE = np.dtype(S.MESSAGE_HEADER)


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


def open_exclusive(path: Path) -> BinaryIO:
    """``path`` opened for writing from byte 0, locked against a second writer: a second
    run given the same ``--mcap`` path is refused before it truncates the first run's file
    (the lock is advisory, so other programs are not stopped; it is released on close)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o666)
    try:
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise OSError(
                    errno.EBUSY, "another bench run is writing this file (choose another --mcap)"
                ) from None
        os.ftruncate(fd, 0)
        return open(fd, "wb")  # the caller owns it; tests wrap this module's open
    except BaseException:
        os.close(fd)
        raise


def check_writable(path: Path) -> str:
    """Why ``path`` cannot be written as a new log ("" when it can), found before a run
    starts: a folder, a read-only place, or a file another run is writing. Leaves an
    existing file's content alone."""
    if path.is_dir():
        return "it is a folder"
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o666)
    except OSError as exc:
        return exc.strerror or str(exc)
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return "another bench run is writing this file (choose another --mcap)"
    except OSError:
        pass  # a file system without locks: the writer finds out for itself
    finally:
        os.close(fd)
    return ""


def utc_now() -> str:
    return datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


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
        self._fh = open_exclusive(self.path)
        st = os.fstat(self._fh.fileno())
        self._identity = (st.st_dev, st.st_ino)
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
        if problem := self.vanished():
            raise OSError(errno.ENOENT, problem)

    def vanished(self) -> str:
        """Why the file written is no longer at ``path`` ("" while it is): deleted, or
        replaced by another file, during the run. Its data is then out of reach, which a
        run must say loudly instead of "log written"."""
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return "the log file was deleted during the run: what was written to it is lost"
        except OSError:
            return ""
        if (st.st_dev, st.st_ino) != self._identity:
            return "the log file was replaced by another file during the run"
        return ""

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


def _compressor(name: str) -> Callable[[bytes], bytes]:
    if name == "zstd":
        import zstandard

        cctx = zstandard.ZstdCompressor(level=1)  # ~2x level 3's speed, same ratio here
        return cctx.compress
    if name == "lz4":
        import lz4.frame

        return lz4.frame.compress
    return bytes
