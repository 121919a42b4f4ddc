"""Reading the bench's MCAP files: :class:`McapLog`, a fast frame reader that survives
truncation (the recorded results, events, metadata and attachments as rows:
:mod:`bench.mcaplog.recorded`).

The file is scanned record by record from the start (not from the summary), so an
unfinished file (kill -9, power loss, disk full) reads exactly like a finished one up to
its last complete chunk; the rest is reported in ``warnings`` and ``lost_bytes``. The
summary, when present, is only checked (CRC, statistics).

Frames come back without per-message Python: each chunk is decompressed once, the offsets
of its ``/can/frames`` messages come from the chunk's MessageIndex (or, if that index was
lost to truncation, from one walk over the chunk's records), and a strided numpy view
gathers the fixed-size records in one fancy index.
"""

from __future__ import annotations

import json
import logging
import os
import struct
import zlib
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bench.mcaplog import schemas as S
from bench.mcaplog.decoders import (
    concat_frames,
    frames_from_records,
    link_error_from_json,
    notice_from_json,
    or_notice,
)
from bench.mcaplog.filebytes import FileBytes
from bench.mcaplog.recovery import (
    SummaryAhead,
    definitions_from_chunks,
    frames_lost_to_damage,
    loose_chunk,
    peek_summary,
    resync,
    truncation_loss,
)
from bench.mcaplog.structure import (
    FOOTER_LEN,
    MAGIC,
    OP_ATTACHMENT,
    OP_CHANNEL,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    OP_HEADER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    OP_NAMES,
    OP_SCHEMA,
    AttachmentInfo,
    ChannelInfo,
    ChunkContent,
    ChunkInfo,
    McapReadError,
    SchemaInfo,
    gather,
    parse_attachment,
    parse_channel,
    parse_chunk,
    parse_schema,
    read_map,
    read_str,
    unpack_at,
    walk_chunk,
)
from devices.base import SourceBatch, SourceNotice
from devices.paths import regular_file_problem
from protocol.frames import empty_frames
from protocol.records import LinkError

log = logging.getLogger("bench.mcaplog.reader")
log.addHandler(logging.NullHandler())  # the commands report ``warnings`` themselves, once


class McapLog:
    """An opened bench MCAP file: its definitions, chunks, metadata and attachments.

    Opening scans the records (cheap: chunk bodies are skipped) and never raises for a
    truncated or damaged tail; only a file that is not MCAP at all raises McapReadError.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        why = regular_file_problem(self.path)  # before opening: a FIFO's open waits forever
        if why.startswith("not a regular file"):
            raise McapReadError(f"{self.path}: cannot open: {why}")
        try:
            self._fh = open(self.path, "rb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise McapReadError(f"{self.path}: cannot open: {exc.strerror or exc}") from None
        self.size = os.fstat(self._fh.fileno()).st_size
        self._mm = FileBytes(self._fh.fileno(), self.size, self.path)  # never a mapping: SIGBUS
        self.library = ""
        self.profile = ""
        self.schemas: dict[int, SchemaInfo] = {}
        self.channels: dict[int, ChannelInfo] = {}
        self.chunks: list[ChunkInfo] = []
        self.metadata: list[tuple[str, dict[str, str]]] = []
        self.attachments: list[AttachmentInfo] = []
        self.data_end: int | None = None  # offset of the DataEnd record
        self.data_section_crc = 0
        self.summary_ok = False
        self.statistics: dict[str, Any] | None = None
        self.lost_bytes = 0
        self.truncation = ""  # the warning about an unfinished file, "" when finished
        self.scan_end = 0  # end of the last complete record of the data section
        self.warnings: list[str] = []
        self.bad_chunks: list[tuple[ChunkInfo, str]] = []
        self.damage: list[str] = []  # what the scan stepped over (see recovery.resync)
        self.foreign_notes: list[str] = []  # channels on /can/frames that are not frames
        self._summary = SummaryAhead()
        self._zstd: Any = None
        try:
            self._scan()
            if self.data_end is not None:
                self._read_footer()
            elif self._summary.channels or self.chunks:
                self._definitions_from_chunks()
            self._note_foreign_frame_channels()
        except BaseException:
            self.close()
            raise
        for w in self.warnings:
            log.warning("%s", w)

    # -- lifecycle -------------------------------------------------------------------------
    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> McapLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- properties ------------------------------------------------------------------------
    @property
    def complete(self) -> bool:
        """Closed cleanly: DataEnd, summary and footer present and consistent."""
        return self.data_end is not None and self.summary_ok

    @property
    def truncated(self) -> bool:
        return self.data_end is None

    def channel_id(self, topic: str) -> int | None:
        """The topic's channel (the lowest id when several channels share the topic, as the
        spec allows: a chunk's offsets give the others' messages under this one)."""
        ids = self.channel_ids(topic)
        return min(ids) if ids else None

    def channel_ids(self, topic: str) -> set[int]:
        """Every channel of ``topic`` that is the bench's: all of them are read (a channel
        of another schema on /can/frames is not: :meth:`foreign`)."""
        return {
            ch.id for ch in self.channels.values() if ch.topic == topic and not self.foreign(ch)
        }

    def foreign(self, ch: ChannelInfo) -> bool:
        """A channel on /can/frames that is not the bench's RawFrame: another message
        encoding, or a schema of another name (the spec lets any channel use any topic; read
        as fixed 38-byte records its messages cost the bench's own frames their chunk). A
        channel without a schema is judged by its content, record by record."""
        if ch.topic != S.FRAME_TOPIC:
            return False
        if ch.message_encoding != "protobuf":
            return True
        schema = self.schemas.get(ch.schema_id)
        return schema is not None and schema.name != S.FRAME_SCHEMA_NAME

    def _note_foreign_frame_channels(self) -> None:
        """A warning for each foreign channel on /can/frames, with its messages not read."""
        foreign = [ch for _, ch in sorted(self.channels.items()) if self.foreign(ch)]
        if not foreign:
            return
        counts = self._channel_counts()
        for ch in foreign:
            schema = self.schemas.get(ch.schema_id)
            name = schema.name if schema is not None else "none"
            self.foreign_notes.append(
                f"{self.path}: channel {ch.id} on {ch.topic} is not the bench's RawFrame "
                f"(schema {name!r}, {ch.message_encoding or 'no'} encoding): its "
                f"{counts.get(ch.id, 0)} messages are not frames and are not replayed"
            )
        self.warnings += self.foreign_notes

    def _aliases(self) -> dict[int, int]:
        """Channel id -> the id its topic is read under (:meth:`channel_id`), for the
        bench's channels that share a topic with a lower id (a foreign one keeps its own)."""
        first: dict[str, int] = {}
        ours = {cid: ch for cid, ch in sorted(self.channels.items()) if not self.foreign(ch)}
        for cid, ch in ours.items():
            first.setdefault(ch.topic, cid)
        return {c: first[ch.topic] for c, ch in ours.items() if first[ch.topic] != c}

    def _with_aliases(self, channels: set[int] | None) -> set[int] | None:
        if channels is None:
            return None
        aliases = self._aliases()
        return channels | {c for c, canon in aliases.items() if canon in channels}

    def foreign_topics(self, ours: set[str] | None = None) -> list[str]:
        """The file's topics when it has some but none of ``ours`` (default: the topics a
        replay reads): an MCAP file of something else, which must not read as empty."""
        ours = ours or {S.FRAME_TOPIC, S.LINK_ERROR_TOPIC, S.NOTICE_TOPIC}
        topics = sorted({ch.topic for ch in self.channels.values()})
        return topics if topics and ours.isdisjoint(topics) else []

    def metadata_dict(self) -> dict[str, dict[str, str]]:
        out: dict[str, dict[str, str]] = {}
        for name, data in self.metadata:
            out[name] = data
        return out

    def attachment(self, name: str) -> bytes | None:
        for att in self.attachments:
            if att.name == name:
                return bytes(self._mm[att.data_offset : att.data_offset + att.size])
        return None

    # -- scanning --------------------------------------------------------------------------
    def _scan(self) -> None:
        """Walk the data section record by record. A record that cannot be read ends the
        walk (an unfinished file), unless the summary's chunk index says where the next
        chunk starts: then the walk skips there (or reads the damaged chunk with the
        index's length) and the skip is counted in ``damage``."""
        mm = self._mm
        size = self.size
        if size < len(MAGIC) or bytes(mm[:8]) != MAGIC:
            if size < len(MAGIC) and MAGIC.startswith(bytes(mm[:size])):
                self.lost_bytes = size
                self.truncation = f"{self.path}: empty MCAP file ({size} bytes): nothing recorded"
                self.warnings.append(self.truncation)
                return
            raise McapReadError(f"{self.path}: not an MCAP file (bad magic)")
        self._summary = peek_summary(mm, size, self.path)
        self.statistics = self._summary.statistics
        self.warnings += self._summary.warnings
        pos = len(MAGIC)
        u_bq = struct.Struct("<BQ").unpack_from
        last_chunk: ChunkInfo | None = None
        loose: list[int] | None = None  # [start, end] of a run of unchunked messages
        repaired: set[int] = set()
        reason = ""
        cut_op = 0
        while True:
            if pos >= size:
                reason = "file ends without a summary (writer did not finish)"
                break
            if pos + 9 > size:
                reason = "file ends inside a record header"
                break
            op, length = u_bq(mm[pos : pos + 9])
            end = pos + 9 + length
            bad = ""
            if end > size:
                name = OP_NAMES.get(op, f"opcode 0x{op:02X}")
                bad = f"file ends inside a {name} record of {length} bytes at byte {pos}"
                cut_op = op
            elif op == 0 or OP_DATA_END < op < 0x80:
                bad = f"unreadable record (opcode 0x{op:02X}) at byte {pos}"
            if not bad:
                if op != OP_MESSAGE_INDEX and last_chunk is not None:
                    last_chunk.index_complete = True
                    last_chunk = None
                if op != OP_MESSAGE and loose is not None and op in (OP_CHUNK, OP_DATA_END):
                    self.chunks.append(loose_chunk(*loose))
                    loose = None
                try:
                    last_chunk = self._record(op, pos, end, last_chunk)
                except (struct.error, UnicodeDecodeError, ValueError) as exc:
                    bad = f"malformed record (opcode 0x{op:02X}) at byte {pos}: {exc}"
                else:
                    if op == OP_MESSAGE:
                        loose = [pos, end] if loose is None else [loose[0], end]
                    elif op == OP_DATA_END:
                        self.scan_end = end
                        return
            if bad:
                step = resync(mm, self._summary.chunk_lengths, pos, bad, repaired)
                if step is None:
                    reason = bad
                    break
                resume, last_chunk, note = step
                self.damage.append(note)
                if last_chunk is not None:  # the index knows this chunk's extent
                    repaired.add(pos)
                    self.chunks.append(last_chunk)
                    end = last_chunk.end
                else:
                    end = resume
            pos = end
            self.scan_end = pos
        if loose is not None:
            self.chunks.append(loose_chunk(*loose))
        # not finished: everything from pos on is lost
        self.lost_bytes = size - self.scan_end
        if cut_op == OP_MESSAGE_INDEX:  # the last chunk is whole: only its index is cut
            est = " (only the last chunk's message index: no messages lost)"
        else:
            fids = self.channel_ids(S.FRAME_TOPIC)
            est = truncation_loss(mm, size, self.scan_end, self.chunks, fids)
        self.truncation = (
            f"{self.path}: unfinished or truncated MCAP file ({reason}); recovered "
            f"{len(self.chunks)} complete chunk(s), lost about {self.lost_bytes} bytes at the "
            f"end{est}"
        )
        self.warnings.append(self.truncation)

    def _record(
        self, op: int, pos: int, end: int, last_chunk: ChunkInfo | None
    ) -> ChunkInfo | None:
        """Take in one data-section record; returns the chunk whose MessageIndex records
        may follow (the new one after a Chunk, else ``last_chunk``)."""
        mm: FileBytes | bytes = self._mm
        body = pos + 9
        if op in (OP_HEADER, OP_SCHEMA, OP_CHANNEL, OP_METADATA, OP_DATA_END):
            mm, body = mm[pos:end], 9  # one read for the record, not one per field
        if op == OP_HEADER:
            self.profile, p = read_str(mm, body)
            self.library, _ = read_str(mm, p)
        elif op == OP_SCHEMA:
            schema = parse_schema(mm, body)
            self.schemas[schema.id] = schema
        elif op == OP_CHANNEL:
            channel = parse_channel(mm, body)
            self.channels[channel.id] = channel
        elif op == OP_CHUNK:
            info = parse_chunk(mm, pos, body, end)
            self.chunks.append(info)
            return info
        elif op == OP_MESSAGE_INDEX:
            if self.chunks and not self.chunks[-1].loose:
                (cid, rec_len) = unpack_at("<HI", mm, body)
                self.chunks[-1].index[cid] = (body + 6, min(rec_len, end - body - 6))
        elif op == OP_METADATA:
            name, p = read_str(mm, body)
            self.metadata.append((name, read_map(mm, p)))
        elif op == OP_ATTACHMENT:
            self.attachments.append(parse_attachment(mm, pos, body, end))
        elif op == OP_DATA_END:
            (self.data_section_crc,) = struct.unpack_from("<I", mm[body : body + 4])
            self.data_end = pos
        return last_chunk

    def _read_footer(self) -> None:
        """After the data section: is the summary there and sound? Definitions only the
        summary or the chunks hold are taken in; damage found on the way is reported."""
        for sid, schema in self._summary.schemas.items():
            self.schemas.setdefault(sid, schema)
        for cid, channel in self._summary.channels.items():
            self.channels.setdefault(cid, channel)
        unindexed = self._definitions_from_chunks()
        self._report_damage(unindexed)
        foot = self.size - 8 - FOOTER_LEN
        if self._summary.problem:
            self.warnings.append(f"{self.path}: {self._summary.problem}")
            return
        if foot < self.scan_end or bytes(self._mm[self.size - 8 :]) != MAGIC:
            self.warnings.append(f"{self.path}: no footer after the data section (summary lost)")
            return
        op, length = unpack_at("<BQ", self._mm, foot)
        if op != OP_FOOTER or length != 20:
            self.warnings.append(f"{self.path}: bad footer record (summary lost)")
            return
        self.summary_ok = True

    def _definitions_from_chunks(self) -> dict[int, bytes | None]:
        return definitions_from_chunks(self.chunks, self.schemas, self.channels, self.decompress)

    def _report_damage(self, unindexed: dict[int, bytes | None]) -> None:
        """Damage the scan stepped over, each note with the frames it cost."""
        if not self.damage:
            return
        fids = self.channel_ids(S.FRAME_TOPIC)
        n = frames_lost_to_damage(self.chunks, fids, self.statistics, self.decompress, unindexed)
        lost = ""
        if n is not None:
            lost = f"; {n} frames lost" if n else "; no frames lost"
        self.damage = [d + lost for d in self.damage]
        self.warnings += [f"{self.path}: {d}" for d in self.damage]

    # -- chunk content ---------------------------------------------------------------------
    def decompress(self, info: ChunkInfo) -> bytes | None:
        """The chunk's records, or None (warned) if they cannot be trusted."""
        raw = self._mm[info.data_offset : info.data_offset + info.data_len]
        try:
            if info.compression == "zstd":
                if self._zstd is None:
                    import zstandard

                    self._zstd = zstandard.ZstdDecompressor()
                buf = self._zstd.decompress(raw, max_output_size=info.uncompressed_size)
            elif info.compression == "lz4":
                import lz4.frame

                buf = lz4.frame.decompress(raw)
            elif info.compression == "":
                buf = bytes(raw)
            else:
                self._bad(info, f"unsupported compression {info.compression!r}")
                return None
        except Exception as exc:
            self._bad(info, f"cannot decompress: {exc}")
            return None
        if len(buf) != info.uncompressed_size:
            self._bad(info, f"size {len(buf)} != {info.uncompressed_size}")
            return None
        if info.crc and zlib.crc32(buf) != info.crc:
            self._bad(info, "CRC mismatch")
            return None
        return buf

    def _bad(self, info: ChunkInfo, why: str) -> None:
        msg = f"{self.path}: chunk at byte {info.offset} skipped: {why}"
        self.bad_chunks.append((info, why))
        self.warnings.append(msg)
        log.warning("%s", msg)
        return None

    def offsets(
        self, info: ChunkInfo, buf: bytes, channels: set[int] | None = None
    ) -> dict[int, np.ndarray]:
        """Offsets of each channel's messages in the chunk, ascending (= write order); the
        messages of channels that share a topic are all under the topic's
        :meth:`channel_id`."""
        aliases = self._aliases()
        found = self._offsets(info, buf, self._with_aliases(channels))
        for cid in [c for c in found if c in aliases]:
            canon, offs = aliases[cid], found.pop(cid)
            both = np.concatenate([found[canon], offs]) if canon in found else offs
            found[canon] = np.sort(both)
        return found

    def _offsets(
        self, info: ChunkInfo, buf: bytes, channels: set[int] | None
    ) -> dict[int, np.ndarray]:
        """Each channel's message offsets from the chunk's MessageIndex when it agrees with
        the chunk (known channels, every offset a Message record of its channel), else from
        a walk of the chunk: a damaged index costs no message."""
        out: dict[int, np.ndarray] = {}
        if info.indexed and info.index.keys() <= self.channels.keys():
            ok = True
            head = np.frombuffer(buf, dtype=np.uint8)
            for cid, (off, nbytes) in info.index.items():
                if channels is not None and cid not in channels:
                    continue
                entries = np.frombuffer(self._mm[off : off + nbytes // 8 * 8], dtype="<u8")
                offs = entries[1::2].astype(np.int64)
                if len(offs) and (offs.max() + S.MESSAGE_HEADER_SIZE > len(buf) or offs.min() < 0):
                    ok = False
                    break
                if len(offs) and (
                    np.any(head[offs] != OP_MESSAGE)
                    or np.any(head[offs + 9] != cid & 0xFF)
                    or np.any(head[offs + 10] != cid >> 8)
                ):
                    ok = False
                    break
                if len(offs) > 1 and np.any(offs[1:] < offs[:-1]):
                    offs = np.sort(offs)
                out[cid] = offs
            if ok:
                return out
        return walk_chunk(buf, channels)

    def iter_chunks(self, channels: set[int] | None = None) -> Iterator[ChunkContent]:
        """The chunks holding messages of ``channels`` (None: every chunk), decompressed.

        A chunk whose MessageIndex names none of them is skipped unread (the writer puts
        the replay's topics in chunks of their own); one without an intact index is read.
        """
        every = self._with_aliases(channels)
        for info in self.chunks:
            if (
                every is not None
                and info.indexed
                and every.isdisjoint(info.index)
                and info.index.keys() <= self.channels.keys()  # else the index is damaged
            ):
                continue
            buf = self.decompress(info)
            if buf is not None:
                yield ChunkContent(info, buf, self.offsets(info, buf, channels))

    # -- frames ----------------------------------------------------------------------------
    def frame_records(self, content: ChunkContent) -> np.ndarray:
        """The chunk's raw-frame records (schemas.FRAME_RECORD_DTYPE), validated."""
        return self._frame_records(content)[0]

    def _frame_records(self, content: ChunkContent) -> tuple[np.ndarray, np.ndarray]:
        """Validated raw-frame records of a chunk and their offsets in it."""
        fid = self.channel_id(S.FRAME_TOPIC)
        offs = content.offsets.get(fid) if fid is not None else None
        none = np.zeros(0, dtype=S.FRAME_RECORD_DTYPE), np.zeros(0, dtype=np.int64)
        if offs is None or len(offs) == 0:
            return none
        if offs.max() + S.FRAME_RECORD_DTYPE.itemsize > len(content.buf):
            self._bad(content.info, "frame message overruns the chunk")
            return none
        recs = gather(content.buf, offs, S.FRAME_RECORD_DTYPE)  # read-only if contiguous
        p = recs["payload"]
        good = (recs["opcode"] == S.MESSAGE_OPCODE) & (recs["length"] == S.FRAME_RECORD_LENGTH)
        good &= np.isin(recs["channel_id"], sorted(self.channel_ids(S.FRAME_TOPIC)))
        for name, value in S.FRAME_PB_CONST.items():
            good &= p[name] == value
        if not good.all():
            bad = int(np.count_nonzero(~good))
            msg = (
                f"{self.path}: {bad} frame message(s) in chunk at byte {content.info.offset} "
                "are not in the bench's RawFrame layout; skipped"
            )
            self.warnings.append(msg)
            log.warning("%s", msg)
            recs, offs = recs[good], offs[good]
        return recs, offs

    def _wanted(self) -> tuple[int | None, int | None, set[int]]:
        """Channel ids of link errors and notices, and every channel a replay reads."""
        fid = self.channel_id(S.FRAME_TOPIC)
        lid = self.channel_id(S.LINK_ERROR_TOPIC)
        nid = self.channel_id(S.NOTICE_TOPIC)
        return lid, nid, {c for c in (fid, lid, nid) if c is not None}

    def iter_batches(
        self, max_frames: int = 65536, *, recorded: bool = False
    ) -> Iterator[tuple[SourceBatch, int]]:
        """SourceBatches in arrival order (frames, link errors, recorded notices); with each,
        the file offset reached.

        Default: chunks merged into batches of up to ``max_frames`` frames (fast; the
        pipeline's output does not depend on batching). ``recorded=True``: the live run's
        own batches, from the batch-start marks (slower, for forensic exactness); a file
        without marks (emulator output) falls back to ``max_frames`` batches.
        """
        if recorded:
            yield from self._iter_recorded(max_frames)
            return
        lid, nid, wanted = self._wanted()
        parts: list[np.ndarray] = []
        errors: list[LinkError] = []
        notices: list[SourceNotice] = []
        pending = 0
        reached = 0
        for content in self.iter_chunks(wanted):
            reached = content.info.end
            recs, _ = self._frame_records(content)
            if len(recs):
                parts.append(frames_from_records(recs))
                pending += len(recs)
            for cid, conv in self._decoders(lid, nid):
                for item in map(conv, content.payloads(cid)):
                    if isinstance(item, LinkError):
                        errors.append(item)
                    else:
                        notices.append(item)
            while pending >= max_frames:
                frames = np.concatenate(parts) if len(parts) > 1 else parts[0]
                yield SourceBatch(frames[:max_frames], errors, notices), reached
                rest = frames[max_frames:]
                parts, errors, notices = ([rest] if len(rest) else []), [], []
                pending = len(rest)
        if parts or errors or notices:
            frames = np.concatenate(parts) if parts else empty_frames()
            yield SourceBatch(frames, errors, notices), reached

    def _decoders(
        self, lid: int | None, nid: int | None
    ) -> list[tuple[int, Callable[[bytes | memoryview], LinkError | SourceNotice]]]:
        """(channel, reader) for the recorded link errors and notices the file has."""
        where = self.path.name
        pairs = ((lid, link_error_from_json), (nid, notice_from_json))
        return [(cid, or_notice(conv, where)) for cid, conv in pairs if cid is not None]

    def _iter_recorded(self, max_frames: int) -> Iterator[tuple[SourceBatch, int]]:
        """The live batches: a batch starts at each frame marked FLAG_BATCH_START; a link
        error or notice belongs to the batch whose frames precede it in the chunk."""
        lid, nid, wanted = self._wanted()
        parts: list[np.ndarray] = []
        errors: list[LinkError] = []
        notices: list[SourceNotice] = []
        pending = 0
        marked = False
        reached = 0
        for content in self.iter_chunks(wanted):
            recs, foffs = self._frame_records(content)
            starts = np.flatnonzero(recs["payload"]["flags"] & S.FLAG_BATCH_START)
            marked = marked or len(starts) > 0
            bounds = foffs[starts]
            frames = frames_from_records(recs)
            extras: list[tuple[int, LinkError | SourceNotice]] = []
            for cid, conv in self._decoders(lid, nid):
                offs = content.offsets.get(cid, np.zeros(0, np.int64)).tolist()
                extras += zip(offs, map(conv, content.payloads(cid)), strict=True)
            extras.sort(key=lambda x: x[0])
            by_seg: dict[int, list[LinkError | SourceNotice]] = {}
            segs = np.searchsorted(bounds, [o for o, _ in extras], side="right").tolist()
            for (_, item), seg in zip(extras, segs, strict=True):
                by_seg.setdefault(seg, []).append(item)
            cuts = [0, *starts.tolist(), len(frames)]
            for k in range(len(cuts) - 1):
                if k > 0 and (parts or errors or notices):
                    yield SourceBatch(concat_frames(parts), errors, notices), reached
                    parts, errors, notices, pending = [], [], [], 0
                piece = frames[cuts[k] : cuts[k + 1]]
                if len(piece):
                    parts.append(piece)
                    pending += len(piece)
                for item in by_seg.get(k, ()):
                    if isinstance(item, LinkError):
                        errors.append(item)
                    else:
                        notices.append(item)
                if not marked and pending >= max_frames:
                    yield SourceBatch(concat_frames(parts), errors, notices), content.info.end
                    parts, errors, notices, pending = [], [], [], 0
            reached = content.info.end
        if parts or errors or notices:
            yield SourceBatch(concat_frames(parts), errors, notices), reached

    def read_frames(self) -> tuple[np.ndarray, list[LinkError], list[SourceNotice]]:
        frames, errors, notices = [], [], []
        for batch, _ in self.iter_batches(1 << 62):
            frames.append(batch.frames)
            errors += batch.link_errors
            notices += batch.notices
        return (np.concatenate(frames) if frames else empty_frames()), errors, notices

    # -- JSON topics -----------------------------------------------------------------------
    def payloads(self, topic: str) -> list[memoryview]:
        cid = self.channel_id(topic)
        if cid is None:
            return []
        out: list[memoryview] = []
        for content in self.iter_chunks({cid}):
            out += content.payloads(cid)
        return out

    def json_topic(self, topic: str) -> list[dict[str, Any]]:
        return [json.loads(bytes(m)) for m in self.payloads(topic)]

    def table(self, topic: str, columns: list[S.Column], dtype: np.dtype) -> np.ndarray:
        return S.decode_rows(self.payloads(topic), columns, dtype)

    def message_counts(self) -> dict[str, int]:
        """Messages per topic, from the MessageIndex records (no decompression) where
        they are intact, else by walking the chunk."""
        return self.per_topic(self._channel_counts())

    def _channel_counts(self) -> Counter[int]:
        """Messages per channel (see :meth:`message_counts`)."""
        counts: Counter[int] = Counter()
        for info in self.chunks:
            if info.indexed:
                for cid, (_, nbytes) in info.index.items():
                    counts[cid] += nbytes // 16
            else:
                buf = self.decompress(info)
                if buf is not None:
                    for cid, offs in walk_chunk(buf, None).items():
                        counts[cid] += len(offs)
        return counts

    def per_topic(self, counts: Mapping[int, int]) -> dict[str, int]:
        """Messages per channel as messages per topic (channels sharing a topic together;
        a foreign channel on /can/frames under ``/can/frames [its schema]``)."""
        by_topic: Counter[str] = Counter()
        for cid, ch in sorted(self.channels.items()):
            by_topic[self._topic_label(ch)] += counts.get(cid, 0)
        return dict(by_topic)

    def _topic_label(self, ch: ChannelInfo) -> str:
        if not self.foreign(ch):
            return ch.topic
        schema = self.schemas.get(ch.schema_id)
        return f"{ch.topic} [{schema.name if schema is not None else ch.message_encoding}]"

    def verify(self) -> list[str]:
        """Check every CRC in the file (data section, summary, chunks, attachments);
        returns the problems found (empty = all good or not recorded)."""
        problems = list(self.damage)
        crc = self.data_section_crc
        if self.data_end is not None and crc:
            calc = 0
            step = 16 << 20
            for start in range(0, self.data_end, step):  # in blocks: files can be GBs
                calc = zlib.crc32(self._mm[start : min(start + step, self.data_end)], calc)
            if calc != crc:
                problems.append("data section CRC mismatch")
        for info in self.chunks:
            buf = self.decompress(info)
            if buf is None:
                problems.append(f"chunk at byte {info.offset}: {self.bad_chunks[-1][1]}")
        for att in self.attachments:
            end = att.record_offset + att.record_length
            (crc,) = unpack_at("<I", self._mm, end - 4)
            if crc and zlib.crc32(self._mm[att.record_offset + 9 : end - 4]) != crc:
                problems.append(f"attachment {att.name}: CRC mismatch")
        problems += [w for w in self.warnings if "summary" in w and "CRC" in w]
        return problems
