"""Fast reader for candump ``-L`` / python-can ``.log`` files: numpy byte arithmetic per column.

A bench log holds millions of lines, and python-can's CanutilsLogReader builds a Message per
line (~a few hundred thousand lines/s). Here the file is read in large chunks, line
boundaries are found with numpy, and lines are grouped by shape (length and position of the
first ``#``). Within a group every line has its fields at the same columns, so one
*template* (taken from the group's first line) is checked against all lines at once and
each field is decoded column by column: timestamps as exact integers, IDs and payloads
through a hex lookup table.

Whatever does not fit a template (CAN FD remote frames, odd spacing, ``0x`` IDs, anything
python-can's quirks accept) falls back to a per-line parse that mirrors python-can's
reader exactly; a line python-can would choke on becomes a ``parse_error`` notice, counted
and never fatal. The contract, held by tests: every line python-can reads gives the same
frame (through :func:`devices.bus.frames_from_messages`), in file order.

Timestamps are ``integer / 10**decimals`` computed in float64; both operands are exact, so
the quotient is the correctly rounded value of the decimal text, i.e. identical to
``float(text)``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from devices.base import DiskFileSource, SourceBatch, SourceNotice
from devices.paths import cannot_read
from protocol.frames import FRAME_DTYPE, empty_frames
from protocol.records import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE

if TYPE_CHECKING:  # python-can only for the per-line fallback: a replay's start need not wait
    import can

CHUNK_BYTES = 1 << 20
"""Bytes parsed per step: large enough to amortise numpy overhead, small enough for memory."""
MAX_FAST_LEN = 512
"""Longer lines (no valid candump line is) go straight to the per-line parser."""
MAX_LINE_BYTES = 1 << 20
"""A 'line' longer than this is garbage (binary file?): reported once and skipped."""
MAX_TEMPLATES_PER_GROUP = 16
"""Templates tried per shape group before the rest of the group is parsed line by line."""

CAN_ERR_FLAG = 0x20000000
CAN_ERR_BUSERROR = 0x00000080
_EXACT_INT_LIMIT = 1 << 53
"""Timestamps with more significant digits are not exact integers in float64: slow path."""

_HEX = np.full(256, 255, dtype=np.uint8)
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"ABCDEF"):
    _HEX[_c] = 10 + _i
_DIG = np.full(256, 255, dtype=np.uint8)
_DIG[48:58] = np.arange(10, dtype=np.uint8)
_HEXCHARS = frozenset("0123456789abcdefABCDEF")
_DIGITS = frozenset("0123456789")
_SNIPPET = 60
UTF8_BOM = b"\xef\xbb\xbf"


@dataclass(frozen=True, slots=True)
class _Template:
    """Column layout of one canonical line shape: ``(I.F) CHAN ID#DATA[ D]``."""

    length: int
    ts_int: tuple[int, int]  # [start, end) columns of the integer digits
    ts_frac: tuple[int, int]
    chan: tuple[int, int]
    ident: tuple[int, int]
    kind: str  # "data", "remote" or "fd"
    payload: tuple[int, int]  # hex data columns ("data"/"fd") or dlc digits ("remote")
    seps: tuple[tuple[int, int], ...]  # (column, byte) that must match exactly
    marker: int  # column of the R of a remote frame / FD flag digit, -1 otherwise
    suffix: int  # column of the R/T direction letter, -1 without


def _template(line: bytes) -> _Template | None:
    """The template of a canonical line, or None when it needs the per-line parser."""
    try:
        text = line.decode("ascii")
    except UnicodeDecodeError:
        return None
    parts = text.split(" ")
    if len(parts) not in (3, 4) or not all(parts):
        return None
    if len(parts) == 4 and parts[3] not in ("R", "r", "T", "t"):
        return None
    ts, chan, frame = parts[:3]
    if len(ts) < 5 or ts[0] != "(" or ts[-1] != ")":
        return None
    whole, dot, frac = ts[1:-1].partition(".")
    if not dot or not whole or not frac or not _DIGITS.issuperset(whole + frac):
        return None
    if len(whole) + len(frac) > 18 or not all(33 <= ord(c) <= 126 for c in chan):
        return None
    ident, hashmark, rest = frame.partition("#")
    if not hashmark or not 1 <= len(ident) <= 8 or not _HEXCHARS.issuperset(ident):
        return None
    c_chan = len(ts) + 1
    c_id = c_chan + len(chan) + 1
    c_hash = c_id + len(ident)
    c_rest = c_hash + 1
    seps = [(0, ord("(")), (1 + len(whole), ord(".")), (len(ts) - 1, ord(")"))]
    seps += [(len(ts), 32), (c_id - 1, 32), (c_hash, ord("#"))]
    marker = -1
    if rest[:1] == "#":  # CAN FD: ##<flag digit><hex data>
        data = rest[2:]
        if len(rest) < 2 or rest[1] not in _DIGITS or len(data) % 2:
            return None
        if not _HEXCHARS.issuperset(data):
            return None
        kind, marker, payload = "fd", c_rest + 1, (c_rest + 2, c_rest + 2 + len(data))
        seps.append((c_rest, ord("#")))
    elif rest[:1] in ("R", "r"):  # remote: R[dlc digits]
        digits = rest[1:]
        if len(digits) > 2 or not _DIGITS.issuperset(digits):
            return None
        kind, marker, payload = "remote", c_rest, (c_rest + 1, c_rest + 1 + len(digits))
    else:
        if len(rest) % 2 or not _HEXCHARS.issuperset(rest):
            return None
        kind, payload = "data", (c_rest, c_rest + len(rest))
    suffix = -1
    if len(parts) == 4:
        suffix = len(text) - 1
        seps.append((len(text) - 2, 32))
    return _Template(
        length=len(text),
        ts_int=(1, 1 + len(whole)),
        ts_frac=(2 + len(whole), len(ts) - 1),
        chan=(c_chan, c_chan + len(chan)),
        ident=(c_id, c_hash),
        kind=kind,
        payload=payload,
        seps=tuple(seps),
        marker=marker,
        suffix=suffix,
    )


def _parse_group(
    a: np.ndarray, starts: np.ndarray, tpl: _Template
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Check ``tpl`` against the lines starting at ``starts`` (all of its length) and decode
    them. Returns (ok mask, columns); columns are meaningful where ok."""
    n = len(starts)
    ok = np.ones(n, dtype=bool)
    step = int(starts[1] - starts[0]) if n > 1 else 0
    if n > 1 and step > 0 and (np.diff(starts) == step).all():
        # consecutive lines of one shape (the usual case): a strided view, no gathers
        block = np.lib.stride_tricks.as_strided(
            a[starts[0] :], shape=(n, tpl.length), strides=(step, 1), writeable=False
        )

        def col(c: int) -> np.ndarray:
            column: np.ndarray = block[:, c]
            return column
    else:

        def col(c: int) -> np.ndarray:
            column: np.ndarray = a[starts + c]
            return column

    for c, byte in tpl.seps:
        ok &= col(c) == byte
    for c in range(*tpl.chan):
        v = col(c)
        ok &= (v >= 33) & (v <= 126)
    if tpl.suffix >= 0:
        v = col(tpl.suffix)
        ok &= (v == 82) | (v == 84) | (v == 114) | (v == 116)  # R T r t

    ticks = np.zeros(n, dtype=np.int64)
    for c in (*range(*tpl.ts_int), *range(*tpl.ts_frac)):
        d = _DIG[col(c)]
        ok &= d != 255
        ticks = ticks * 10 + d
    ok &= ticks < _EXACT_INT_LIMIT
    t = ticks / float(10 ** (tpl.ts_frac[1] - tpl.ts_frac[0]))

    ident = np.zeros(n, dtype=np.uint64)
    for c in range(*tpl.ident):
        h = _HEX[col(c)]
        ok &= h != 255
        ident = (ident << np.uint64(4)) | h
    ident = ident.astype(np.uint32)

    data = np.zeros((n, 8), dtype=np.uint8)
    flags = np.zeros(n, dtype=np.uint8)
    if tpl.ident[1] - tpl.ident[0] > 3:
        flags |= FLAG_EXTENDED
    if tpl.kind == "remote":
        v = col(tpl.marker)
        ok &= (v == 82) | (v == 114)
        dlc = np.zeros(n, dtype=np.int64)
        for c in range(*tpl.payload):
            d = _DIG[col(c)]
            ok &= d != 255
            dlc = dlc * 10 + d
        flags |= FLAG_REMOTE
    else:
        if tpl.kind == "fd":
            ok &= _DIG[col(tpl.marker)] != 255
            flags |= FLAG_FD
        p0, p1 = tpl.payload
        nbytes = (p1 - p0) // 2
        for k in range(nbytes):
            hi = _HEX[col(p0 + 2 * k)]
            lo = _HEX[col(p0 + 2 * k + 1)]
            ok &= (hi != 255) & (lo != 255)
            if k < 8:
                data[:, k] = (hi << 4) | lo
        dlc = np.full(n, nbytes, dtype=np.int64)

    # python-can: an id with the error flag and the bus-error class is an error frame
    # (a default Message: id 0, no data, is_extended_id True)
    err = ((ident & CAN_ERR_FLAG) != 0) & ((ident & CAN_ERR_BUSERROR) != 0)
    ident &= np.uint32(0x1FFFFFFF)
    if err.any():
        ident[err] = 0
        dlc[err] = 0
        data[err] = 0
        flags[err] = FLAG_ERROR | FLAG_EXTENDED
    return ok, {"t": t, "id": ident, "dlc": np.minimum(dlc, 255), "flags": flags, "data": data}


def message_from_line(line: str) -> can.Message | None:
    """python-can's CanutilsLogReader logic for one line (None for a blank line).

    Kept line-for-line equivalent so the fallback path gives python-can's answer for
    anything the fast path leaves out; raises ValueError/IndexError where python-can would.
    """
    import can

    temp = line.strip()
    if not temp:
        return None
    if temp[-2:].lower() in (" r", " t"):
        timestamp_string, channel_string, frame, is_rx_string = temp.split()
        is_rx = is_rx_string.strip().lower() == "r"
    else:
        timestamp_string, channel_string, frame = temp.split()
        is_rx = True
    timestamp = float(timestamp_string[1:-1])
    can_id_string, data = frame.split("#", maxsplit=1)
    is_extended = len(can_id_string) > 3
    can_id = int(can_id_string, 16)
    is_fd = brs = esi = False
    if data and data[0] == "#":
        is_fd = True
        fd_flags = int(data[1])
        brs = bool(fd_flags & 0x01)
        esi = bool(fd_flags & 0x02)
        data = data[2:]
    data_bin: bytearray | None
    if data and data[0].lower() == "r":
        is_remote_frame = True
        dlc = int(data[1:]) if len(data) > 1 else 0
        data_bin = None
    else:
        is_remote_frame = False
        dlc = len(data) // 2
        data_bin = bytearray()
        for i in range(0, len(data), 2):
            data_bin.append(int(data[i : i + 2], 16))
    if can_id & CAN_ERR_FLAG and can_id & CAN_ERR_BUSERROR:
        return can.Message(timestamp=timestamp, is_error_frame=True)
    return can.Message(
        timestamp=timestamp,
        arbitration_id=can_id & 0x1FFFFFFF,
        is_extended_id=is_extended,
        is_remote_frame=is_remote_frame,
        is_fd=is_fd,
        is_rx=is_rx,
        bitrate_switch=brs,
        error_state_indicator=esi,
        dlc=dlc,
        data=data_bin,
        channel=channel_string,
    )


def _snippet(raw: bytes) -> str:
    text = raw[:_SNIPPET].decode("utf-8", "backslashreplace")
    return repr(text + ("..." if len(raw) > _SNIPPET else ""))


def _slow_line(raw: bytes) -> tuple[list[can.Message], str | None]:
    """Per-line parse of one physical line; python-can reads text with universal newlines,
    so a stray CR splits it into several lines there too."""
    from devices.bus import one_line

    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        return [], "not UTF-8 text"
    msgs: list[can.Message] = []
    for sub in text.replace("\r\n", "\n").replace("\r", "\n").split("\n"):
        try:
            msg = message_from_line(sub)
        except (ValueError, IndexError, TypeError, OverflowError) as exc:
            return msgs, f"not a candump line ({one_line(exc)})"
        if msg is not None:
            msgs.append(msg)
    return msgs, None


@dataclass(slots=True)
class ParsedChunk:
    frames: np.ndarray  # FRAME_DTYPE, file order
    frame_lines: np.ndarray  # int64 line index (0-based within the chunk) of every frame
    notices: list[tuple[int, SourceNotice]]  # (line index within the chunk, notice)
    n_lines: int


def parse_candump_bytes(buf: bytes, first_line: int = 1) -> ParsedChunk:
    """Parse whole lines of a candump log. ``first_line`` numbers the notices."""
    a = np.frombuffer(buf, dtype=np.uint8)
    nl = np.flatnonzero(a == 10)
    starts = np.concatenate(([0], nl + 1)).astype(np.int64)
    ends = np.concatenate((nl, [len(a)])).astype(np.int64)
    if len(a) and a[-1] == 10:
        starts, ends = starts[:-1], ends[:-1]
    n = len(starts)
    if not n:
        return ParsedChunk(empty_frames(), np.zeros(0, np.int64), [], 0)
    nonempty = ends > starts
    cr = np.zeros(n, dtype=bool)
    cr[nonempty] = a[ends[nonempty] - 1] == 13  # CRLF files: drop the CR like text mode does
    ends = ends - cr
    lengths = ends - starts

    hashes = np.flatnonzero(a == 35)
    if len(hashes):
        k = np.minimum(np.searchsorted(hashes, starts), len(hashes) - 1)
        hash_at = hashes[k]
        has_hash = (hash_at >= starts) & (hash_at < ends)
    else:
        hash_at = starts
        has_hash = np.zeros(n, dtype=bool)

    out = np.zeros(n, dtype=FRAME_DTYPE)
    have = np.zeros(n, dtype=bool)
    fast = has_hash & (lengths <= MAX_FAST_LEN)
    slow_rows: list[np.ndarray] = [np.flatnonzero(~fast & (lengths > 0))]

    rows = np.flatnonzero(fast)
    key = lengths[rows] * 1024 + (hash_at[rows] - starts[rows])
    order = np.argsort(key, kind="stable")
    rows, key = rows[order], key[order]
    bounds = np.flatnonzero(np.diff(key)) + 1
    for group in np.split(rows, bounds):
        pending = group
        for _ in range(MAX_TEMPLATES_PER_GROUP):
            if not len(pending):
                break
            r0 = int(pending[0])
            tpl = _template(buf[starts[r0] : ends[r0]])
            ok = None
            if tpl is not None:
                ok, cols = _parse_group(a, starts[pending], tpl)
            if ok is None or not ok[0]:
                slow_rows.append(pending[:1])
                pending = pending[1:]
                continue
            if ok.all():  # the usual case: no boolean compress
                target = slice(None) if len(pending) == n else pending
                for name, values in cols.items():
                    out[name][target] = values
                have[target] = True
                pending = pending[:0]
                continue
            hit = pending[ok]
            for name, values in cols.items():
                out[name][hit] = values[ok]
            have[hit] = True
            pending = pending[~ok]
        slow_rows.append(pending)

    notices: list[tuple[int, SourceNotice]] = []
    extra: list[tuple[int, int, np.ndarray]] = []
    for r in np.sort(np.concatenate(slow_rows)).tolist():
        raw = buf[starts[r] : ends[r]]
        msgs: list[can.Message]
        error: str | None
        if len(raw) > MAX_LINE_BYTES:
            msgs, error = [], f"line of {len(raw)} bytes"
        else:
            msgs, error = _slow_line(raw)
        if msgs:
            from devices.bus import frames_from_messages

            frames = frames_from_messages(msgs)
            out[r] = frames[0]
            have[r] = True
            extra.extend((r, j, frames[j : j + 1]) for j in range(1, len(frames)))
        if error is not None:
            detail = f"line {first_line + r}: {error}: {_snippet(raw)}"
            notices.append((r, SourceNotice(math.nan, "parse_error", detail)))

    if have.all():
        frame_lines, frames = np.arange(n, dtype=np.int64), out
    else:
        frame_lines, frames = np.flatnonzero(have), out[have]
    if extra:  # lines split by a stray CR: put their extra frames right after the first
        keys = np.concatenate((frame_lines * 4096, [r * 4096 + j for r, j, _ in extra]))
        frames = np.concatenate([frames, *(f for _, _, f in extra)])
        frame_lines = np.concatenate((frame_lines, [r for r, _, _ in extra]))
        order = np.argsort(keys, kind="stable")
        frames, frame_lines = frames[order], frame_lines[order]
    return ParsedChunk(frames, frame_lines, notices, n)


def read_candump(path: str | os.PathLike[str]) -> tuple[np.ndarray, list[SourceNotice]]:
    """A whole candump log as one FRAME_DTYPE array plus its notices (tests, tools)."""
    src = CandumpFileSource(path)
    parts, notices = [], []
    for batch in src.batches(max_frames=1 << 30):
        parts.append(batch.frames)
        notices.extend(batch.notices)
    return (np.concatenate(parts) if parts else empty_frames()), notices


class CandumpFileSource(DiskFileSource):
    """A candump ``.log`` as batches; counts lines, frames and parse errors as it goes."""

    def __init__(self, path: str | os.PathLike[str], chunk_bytes: int = CHUNK_BYTES) -> None:
        self.path = Path(path)
        self.description = f"candump log {self.path}"
        self.chunk_bytes = max(1024, int(chunk_bytes))
        try:
            self._size = self.path.stat().st_size
            with self.path.open("rb"):
                pass
        except OSError as exc:
            raise cannot_read(self.path, exc) from exc
        self.lines = 0
        self.frames = 0
        self.parse_errors = 0

    def batches(self, max_frames: int = 65536) -> Iterator[SourceBatch]:
        max_frames = max(1, int(max_frames))
        self._pos = self.lines = self.frames = self.parse_errors = 0
        with self._open_binary() as f:
            carry = b""
            skipping = False  # inside an overlong line that was already reported
            first = True
            while True:
                try:
                    chunk = f.read(self.chunk_bytes)
                except OSError as exc:
                    yield self._read_failed(exc)
                    return
                eof = not chunk
                if first:
                    chunk, first = chunk.removeprefix(UTF8_BOM), False  # an editor's BOM
                data, carry = carry + chunk, b""
                if skipping:
                    cut = data.find(b"\n")
                    if cut >= 0 or eof:
                        self.lines += 1
                        skipping = False
                    data = data[cut + 1 :] if cut >= 0 else b""
                if not eof:
                    cut = data.rfind(b"\n")
                    if cut < 0:
                        if len(data) > MAX_LINE_BYTES:
                            self.parse_errors += 1
                            skipping = True
                            detail = f"line {self.lines + 1}: longer than {MAX_LINE_BYTES} bytes"
                            notice = SourceNotice(math.nan, "parse_error", detail)
                            yield SourceBatch(notices=[notice])
                        else:
                            carry = data
                        self._pos = f.tell() - len(carry)
                        continue
                    data, carry = data[: cut + 1], data[cut + 1 :]
                if data:
                    yield from self._emit(parse_candump_bytes(data, self.lines + 1), max_frames)
                self._pos = f.tell() - len(carry)
                if eof:
                    break
        self._check_unchanged(self.frames)

    def _emit(self, chunk: ParsedChunk, max_frames: int) -> Iterator[SourceBatch]:
        self.lines += chunk.n_lines
        self.frames += len(chunk.frames)
        self.parse_errors += len(chunk.notices)
        n = len(chunk.frames)
        nb = max(1, -(-n // max_frames))
        per_batch: list[list[SourceNotice]] = [[] for _ in range(nb)]
        for row, notice in chunk.notices:
            at = int(np.searchsorted(chunk.frame_lines, row))
            per_batch[min(at // max_frames, nb - 1)].append(notice)
        for b in range(nb):
            batch = SourceBatch(
                chunk.frames[b * max_frames : (b + 1) * max_frames], [], per_batch[b]
            )
            if batch:
                yield batch
