"""Reading a damaged or unfinished MCAP file as far as it can be trusted: the summary read
ahead of the data section, stepping over damage with its chunk index, definitions that
live only inside chunks, and what the damage or the truncation cost in frames.

Pure functions over the file's bytes and what :class:`bench.mcaplog.reader.McapLog` has
scanned so far; they never raise for malformed input (that becomes a warning)."""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bench.mcaplog.structure import (
    FOOTER_LEN,
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_FOOTER,
    OP_SCHEMA,
    OP_STATISTICS,
    ChannelInfo,
    ChunkInfo,
    SchemaInfo,
    parse_channel,
    parse_chunk,
    parse_schema,
    read_statistics,
    unpack_at,
    walk_chunk,
    walk_records,
)

Decompress = Callable[[ChunkInfo], bytes | None]
"""The reader's chunk decompression: None (and warned) when the chunk cannot be trusted."""


@dataclass(slots=True)
class SummaryAhead:
    """What the summary section says, read before the data section."""

    schemas: dict[int, SchemaInfo] = field(default_factory=dict)
    channels: dict[int, ChannelInfo] = field(default_factory=dict)
    chunk_lengths: dict[int, int] = field(default_factory=dict)  # offset -> record length
    statistics: dict[str, Any] | None = None
    problem: str = ""  # why the summary is not to be trusted, "" when it is (or absent)
    warnings: list[str] = field(default_factory=list)


def peek_summary(mm: Any, size: int, path: object) -> SummaryAhead:
    """The summary section, if the footer points at one: its chunk index lets the scan step
    over a damaged record, and other writers keep definitions there (or only inside
    chunks). Anything malformed here is a warning, never an exception."""
    out = SummaryAhead()
    foot = size - 8 - FOOTER_LEN
    if foot < len(MAGIC) or bytes(mm[size - 8 :]) != MAGIC:
        return out
    op, length, sstart, soff, crc = unpack_at("<BQQQI", mm, foot)
    if op != OP_FOOTER or length != 20 or not sstart:
        return out
    if not len(MAGIC) <= sstart <= foot:
        out.problem = "footer points outside the file (summary lost)"
        return out
    summary = bytes(mm[sstart : foot + 1 + 8 + 16])  # read once: one read, not one per field
    if crc and zlib.crc32(summary) != crc:
        out.problem = "summary CRC mismatch (summary ignored)"
        return out
    end = (soff if sstart <= soff <= foot else foot) - sstart
    pos = 0
    try:
        while pos + 9 <= end:
            rop, rlen = struct.unpack_from("<BQ", summary, pos)
            rend = pos + 9 + rlen
            if rend > end:
                raise ValueError(f"record at byte {sstart + pos} overruns the summary")
            if rop == OP_STATISTICS:
                try:
                    out.statistics = read_statistics(summary, pos + 9, rend)
                except (struct.error, ValueError) as exc:
                    out.warnings.append(
                        f"{path}: malformed Statistics record in the summary "
                        f"({exc}): statistics ignored"
                    )
            elif rop == OP_SCHEMA:
                schema = parse_schema(summary, pos + 9)
                out.schemas[schema.id] = schema
            elif rop == OP_CHANNEL:
                channel = parse_channel(summary, pos + 9)
                out.channels[channel.id] = channel
            elif rop == OP_CHUNK_INDEX:
                start, clen = struct.unpack_from("<QQ", summary, pos + 9 + 16)
                if len(MAGIC) <= start and start + clen <= sstart and clen > 9:
                    out.chunk_lengths[start] = clen
            pos = rend
    except (struct.error, UnicodeDecodeError, ValueError) as exc:
        out.warnings.append(f"{path}: malformed summary section ({exc})")
    return out


def loose_chunk(start: int, end: int) -> ChunkInfo:
    """Unchunked messages (and any definitions between them) read as one uncompressed
    chunk: the chunk readers walk it like a chunk without a MessageIndex."""
    n = end - start
    return ChunkInfo(start, n, 0, 0, n, 0, "", start, n, loose=True)


def resync(
    mm: Any, chunk_lengths: dict[int, int], pos: int, why: str, repaired: set[int]
) -> tuple[int, ChunkInfo | None, str] | None:
    """Where the walk goes on after an unreadable record at ``pos``, with the damage note.

    ``(pos, chunk, note)`` when the summary's chunk index has a chunk there whose header is
    damaged but not its content (the chunk read with the index's length); else
    ``(next indexed chunk, None, note)``; None without a usable chunk index."""
    if not chunk_lengths:
        return None
    if pos in chunk_lengths and pos not in repaired:
        try:
            info = parse_chunk(mm, pos, pos + 9, pos + chunk_lengths[pos])
        except (struct.error, UnicodeDecodeError, ValueError):
            pass
        else:
            note = (
                f"damaged record header at byte {pos} ({why}); "
                "the chunk was read with the length in the chunk index"
            )
            return pos, info, note
    later = [s for s in chunk_lengths if s > pos]
    if not later:
        return None
    nxt = min(later)
    return nxt, None, f"unreadable bytes {pos}..{nxt} skipped ({why})"


def definitions_from_chunks(
    chunks: list[ChunkInfo],
    schemas: dict[int, SchemaInfo],
    channels: dict[int, ChannelInfo],
    decompress: Decompress,
) -> dict[int, bytes | None]:
    """Take in Schema and Channel records that live only inside chunks (the spec allows it;
    the mcap package's writer puts them there): looked for only when a chunk's index names
    a channel no top-level record defined, or an unindexed chunk is all there is.

    Returns the unindexed chunks it decompressed (offset -> records, None when
    untrusted), so that counting their frames does not decompress them again."""
    known = set(channels)
    wanted = [
        c for c in chunks
        if (c.indexed and not known.issuperset(c.index)) or (not c.indexed and not known)
    ]  # fmt: skip
    unindexed: dict[int, bytes | None] = {}
    for info in wanted:
        buf = decompress(info)
        if not info.indexed:
            unindexed[info.offset] = buf
        if buf is None:
            continue
        for op, body, _ in walk_records(buf, {OP_SCHEMA, OP_CHANNEL}):
            try:
                if op == OP_SCHEMA:
                    schema = parse_schema(buf, body)
                    schemas.setdefault(schema.id, schema)
                else:
                    channel = parse_channel(buf, body)
                    channels.setdefault(channel.id, channel)
            except (struct.error, UnicodeDecodeError, ValueError):
                continue
    return unindexed


def frames_lost_to_damage(
    chunks: list[ChunkInfo],
    frame_channels: set[int],
    statistics: dict[str, Any] | None,
    decompress: Decompress,
    unindexed: dict[int, bytes | None],
) -> int | None:
    """Frames the damage cost: the summary's statistics against what the readable chunks
    hold (their indexes, or a walk of an unindexed chunk); None when not countable."""
    fids = frame_channels
    counted = statistics["channel_message_counts"] if statistics is not None else {}
    if not fids or not fids.issubset(counted):
        return None
    have = 0
    for c in chunks:
        if c.indexed:
            have += sum(c.index[f][1] // 16 for f in fids if f in c.index)
        else:
            buf = unindexed[c.offset] if c.offset in unindexed else decompress(c)
            walked = walk_chunk(buf, fids) if buf is not None else {}
            have += sum(len(offs) for offs in walked.values())
    return max(0, sum(counted[f] for f in fids) - have)


def truncation_loss(
    mm: Any, size: int, scan_end: int, chunks: list[ChunkInfo], frame_channels: set[int]
) -> str:
    """'(~N frames, ~S s)' for the bytes after ``scan_end``: for a chunk cut short, from
    its own header (uncompressed size, time span) scaled by the complete chunks' frames
    per byte; otherwise from the complete chunks' average compressed density."""
    lost = size - scan_end
    if lost <= 0 or not chunks:
        return ""
    indexed = [c for c in chunks if c.indexed]
    frames = sum(c.index.get(f, (0, 0))[1] // 16 for c in indexed for f in frame_channels)
    if frames <= 0:
        return ""
    head = scan_end
    op = mm[head] if head < size else 0
    if op == OP_CHUNK and head + 9 + 24 <= size:
        t0, t1, usize = unpack_at("<QQQ", mm, head + 9)
        per_byte = frames / max(1, sum(c.uncompressed_size for c in indexed))
        span = f", {(t1 - t0) / 1e9:.1f} s" if t1 >= t0 else ""
        return f" (the last chunk, cut short: ~{int(usize * per_byte)} frames{span})"
    comp = sum(c.data_len for c in indexed)
    span_s = (chunks[-1].end_time - chunks[0].start_time) / 1e9
    secs = f", ~{lost * span_s / comp:.1f} s" if span_s > 0 and comp else ""
    return f" (~{int(lost * frames / max(1, comp))} frames{secs})"
