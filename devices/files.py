r"""The readers of recorded logs other than candump's, as :class:`FileSource`\ s.

* ``.asc`` ``.blf`` ``.trc`` ``.csv``  python-can's LogReader, batched
* ``.bin``  raw UART capture (COBS packets), ``t`` = NaN (the UART carries no time)

(``.log``, candump ``-L`` text, is :mod:`devices.candump`'s.) :func:`devices.formats.open_log`
opens every replayable log by its extension.

Operator mistakes (missing file, unknown extension, unreadable or not-a-log file) are one
:class:`BenchError` line at open time; corruption found while reading ends the stream
with a "truncated" notice after every frame read before it. python-can readers raise
anything from struct.error to AssertionError on bad input, so they are wrapped whole.
"""

from __future__ import annotations

import contextlib
import math
import os
import struct
import zlib
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import Any

import can
import numpy as np
from can.io.blf import (
    FILE_HEADER_SIZE,
    LOG_CONTAINER,
    LOG_CONTAINER_STRUCT,
    NO_COMPRESSION,
    OBJ_HEADER_BASE_STRUCT,
    ZLIB_DEFLATE,
    BLFParseError,
    BLFReader,
)

from devices.base import DiskFileSource, SourceBatch, SourceNotice
from devices.bus import frames_from_messages, one_line
from devices.candump import UTF8_BOM
from devices.errors import BenchError
from devices.paths import cannot_read, check_readable
from devices.text_logs import CSV_HEADER, TEXT_FORMATS, TextFormat, read_text_log
from protocol.frames import empty_frames
from protocol.records import LinkError
from protocol.uart import MAX_BODY, deframe_bytes

UART_CHUNK_BYTES = 4 << 20


class _GuardedBLFReader(BLFReader):
    """BLFReader that refuses objects shorter than their own header, and reads past an
    object whose size field claims more bytes than the file has left.

    python-can's inner loop never advances past an object whose size field is 0, so a
    corrupt file would spin forever (python-can issue #1584); here it is a BLFParseError.
    Its outer loop reads an object's size as given: a size of 0xFFFFFFF0 swallows the rest
    of the file as one container (a 4 GB read), whose compressed stream ends long before
    the file does, and every later container is lost without a word. Here such an object
    ends where the next object header begins; each is noted in ``damage``.
    """

    def __init__(self, file: Any, **kwargs: Any) -> None:
        super().__init__(file, **kwargs)
        self.damage: list[str] = []
        self._end = os.fstat(self.file.fileno()).st_size

    def __iter__(self) -> Generator[can.Message, None, None]:
        head = OBJ_HEADER_BASE_STRUCT.size
        while True:
            at = self.file.tell()
            data = self.file.read(head)
            if not data:
                break
            signature, _, _, obj_size, obj_type = OBJ_HEADER_BASE_STRUCT.unpack(data)
            if signature != b"LOBJ":
                raise BLFParseError(f"no object header at byte {at}")
            if at + obj_size > self._end and self.file_size <= self._end:
                # not a cut file (its header's size is all there): the size field is damaged
                obj_data = self._to_next_object()
                self.damage.append(
                    f"object at byte {at} claims {obj_size} bytes, {self._end - at} are left: "
                    f"read as {head + len(obj_data)} bytes, up to the next object"
                )
            else:
                obj_data = self.file.read(obj_size - head)
                self.file.read(obj_size % 4)  # padding
            if obj_type == LOG_CONTAINER:
                method, _ = LOG_CONTAINER_STRUCT.unpack_from(obj_data)
                container = obj_data[LOG_CONTAINER_STRUCT.size :]
                if method == NO_COMPRESSION:
                    yield from self._parse_container(container)
                elif method == ZLIB_DEFLATE:
                    yield from self._parse_container(zlib.decompressobj().decompress(container))
                else:
                    self.damage.append(f"container at byte {at}: unknown compression {method}")
        self.stop()

    def _to_next_object(self, block: int = 1 << 20) -> bytes:
        """The bytes from here to the next container's header (or the end), the file left
        there. (An uncompressed container holds message objects, also signed LOBJ.)"""
        start = self.file.tell()
        data = bytearray()
        while more := self.file.read(block):
            at = max(0, len(data) - 15)  # a header may straddle two blocks
            data += more
            while (at := data.find(b"LOBJ", at)) >= 0 and at + 16 <= len(data):
                if OBJ_HEADER_BASE_STRUCT.unpack_from(data, at)[4] == LOG_CONTAINER:
                    del data[at:]
                    self.file.seek(start + len(data))
                    return bytes(data)
                at += 4
        self.file.seek(start + len(data))
        return bytes(data)

    def _parse_data(self, data: bytes) -> Iterator[can.Message]:
        pos, end, header = 0, len(data), OBJ_HEADER_BASE_STRUCT.size
        while True:
            at = data.find(b"LOBJ", pos, pos + 8)
            if at < 0 or at + header > end:
                break
            obj_size = OBJ_HEADER_BASE_STRUCT.unpack_from(data, at)[3]
            if obj_size < header:
                raise BLFParseError(f"object of size {obj_size} at offset {at}")
            if at + obj_size > end:
                break
            pos = at + obj_size
        yield from super()._parse_data(data)


_CSV_HEADER = CSV_HEADER
"""The header line python-can's CSVWriter writes and its CSVReader skips unread."""
_RESULTS_CSV_START = "time_s,counter,"
"""How a bench results CSV (bench.replay.CsvSink) begins."""

_READERS = {".blf": _GuardedBLFReader}
_READER_DEFAULTS: dict[str, dict[str, Any]] = {".asc": {"relative_timestamp": False}}
"""ASC times are absolute (from the file's start date) like every other format's."""
_TRUNCATION_ERRORS = (struct.error, EOFError, zlib.error, BLFParseError)
"""Reader failures that mean the file ends (or breaks) early rather than bad text."""


class CanLogReaderSource(DiskFileSource):
    """A .asc/.blf/.trc/.csv log through python-can's readers, in batches of frames.

    The text formats go through :func:`devices.text_logs.read_text_log`: every frame line
    python-can skips or raises on is a ``parse_error`` notice and reading goes on."""

    def __init__(self, path: str | os.PathLike[str], **reader_kwargs: Any) -> None:
        self.path = Path(path)
        self.description = f"{self.path.suffix.lstrip('.')} log {self.path}"
        self._size = check_readable(self.path)
        self._kwargs = {**_READER_DEFAULTS.get(self.path.suffix.lower(), {}), **reader_kwargs}
        self.frames = 0
        self.parse_errors = 0
        self._text = TEXT_FORMATS.get(self.path.suffix.lower())
        self._reader: can.io.generic.MessageReader | None = None
        if self._text is None:
            self._reader = self._open()
        else:
            self._check_format()

    def _open(self) -> can.io.generic.MessageReader:
        """Open the reader now, so a file that is not this format fails at open time."""
        self._check_format()
        cls = _READERS.get(self.path.suffix.lower())
        try:
            if cls is not None:
                return cls(self.path, **self._kwargs)
            return can.LogReader(self.path, **self._kwargs)
        except Exception as exc:  # python-can raises struct.error, ValueError, Unicode...
            raise BenchError(f"cannot read log {self.path}: {one_line(exc)}") from exc

    def _check_format(self) -> None:
        """What python-can would misreport: an empty or cut BLF ("unpack requires a buffer
        of 72 bytes"), a CSV that is not python-can's ("too many values to unpack")."""
        suffix = self.path.suffix.lower()
        if suffix == ".blf" and self._size < FILE_HEADER_SIZE:
            what = "empty file" if self._size == 0 else f"{self._size} bytes"
            raise BenchError(
                f"cannot read log {self.path}: not a BLF log ({what}; a BLF file starts with "
                f"a {FILE_HEADER_SIZE}-byte header)"
            )
        if suffix == ".csv":
            try:
                with self.path.open("rb") as f:
                    head = f.readline(4096).removeprefix(UTF8_BOM).decode("utf-8", "replace")
                head = head.strip()
            except OSError as exc:
                raise cannot_read(self.path, exc) from exc
            if self._size and head != _CSV_HEADER:
                hint = (
                    " (a bench results CSV: replay the run's .mcap)"
                    if head.startswith(_RESULTS_CSV_START)
                    else ""
                )
                raise BenchError(
                    f"cannot read log {self.path}: not a python-can CSV log{hint}: its header "
                    f"is {head[:60]!r}, expected {_CSV_HEADER!r}"
                )

    def _tell(self, reader: can.io.generic.MessageReader) -> None:
        f = getattr(reader, "file", None)
        raw = getattr(f, "buffer", f)  # a text file cannot tell() while iterated
        with contextlib.suppress(AttributeError, OSError, ValueError):
            self._pos = int(raw.tell())  # type: ignore[union-attr]  # no file: suppressed

    def batches(self, max_frames: int = 65536) -> Iterator[SourceBatch]:
        max_frames = max(1, int(max_frames))
        if self._text is not None:
            yield from self._text_batches(self._text, max_frames)
            return
        reader = self._reader if self._reader is not None else self._open()
        self._reader = None
        self._pos = self.frames = 0
        msgs: list[can.Message] = []
        try:
            for msg in reader:
                msgs.append(msg)
                if len(msgs) >= max_frames:
                    self._tell(reader)
                    self.frames += len(msgs)
                    yield SourceBatch(frames_from_messages(msgs))
                    msgs = []
        except Exception as exc:  # any reader failure mid-file: keep what was read
            self.frames += len(msgs)
            kind = "truncated" if isinstance(exc, _TRUNCATION_ERRORS) else "parse_error"
            detail = f"{self.path}: reading stopped after {self.frames} frames: {one_line(exc)}"
            declared = getattr(reader, "object_count", 0)  # a BLF header's count: the loss
            if isinstance(declared, int) and declared > self.frames:
                detail += f" (its header declares {declared} objects)"
            yield SourceBatch(
                frames_from_messages(msgs), [], [SourceNotice(math.nan, kind, detail)]
            )
            return
        finally:
            reader.stop()
        self._pos = self._size
        self.frames += len(msgs)
        self._check_unchanged(self.frames)
        notices = [
            SourceNotice(math.nan, "parse_error", f"{self.path}: {d}")
            for d in getattr(reader, "damage", ())
        ]
        declared = getattr(reader, "file_size", 0)  # BLF headers record the final size
        if isinstance(declared, int) and declared > self._size:
            # python-can stops quietly at a cut BLF container; say so
            detail = f"{self.path}: file is {self._size} bytes, its header says {declared}"
            notices.append(SourceNotice(math.nan, "truncated", detail))
        elif not self.frames and self._size:
            # python-can's ASC reader skips every line it does not recognise
            detail = f"{self.path}: no CAN frames found (not a {self.path.suffix} log?)"
            notices.append(SourceNotice(math.nan, "parse_error", detail))
        if msgs or notices:
            yield SourceBatch(frames_from_messages(msgs), [], notices)

    def _text_batches(self, fmt: TextFormat, max_frames: int) -> Iterator[SourceBatch]:
        self._pos = self.frames = self.parse_errors = 0
        f = self._open_binary()
        msgs: list[can.Message] = []
        notices: list[SourceNotice] = []
        try:
            for item in read_text_log(fmt, f, self.path, **self._kwargs):
                if isinstance(item, SourceNotice):
                    notices.append(item)
                    self.parse_errors += 1
                else:
                    msgs.append(item)
                if len(msgs) >= max_frames or len(notices) >= max_frames:
                    self._pos = _tell_or(f, self._pos)
                    self.frames += len(msgs)
                    yield SourceBatch(frames_from_messages(msgs), [], notices)
                    msgs, notices = [], []
        except OSError as exc:
            self.frames += len(msgs)
            yield SourceBatch(frames_from_messages(msgs), [], notices)
            yield self._read_failed(exc)
            return
        finally:
            f.close()
        self._pos = self._size
        self.frames += len(msgs)
        self._check_unchanged(self.frames)
        if not self.frames and not self.parse_errors and self._size:
            detail = f"{self.path}: no CAN frames found (not a {self.path.suffix} log?)"
            notices.append(SourceNotice(math.nan, "parse_error", detail))
        if msgs or notices:
            yield SourceBatch(frames_from_messages(msgs), [], notices)

    def close(self) -> None:
        if self._reader is not None:
            self._reader.stop()
            self._reader = None


def _tell_or(f: Any, default: int) -> int:
    try:
        return int(f.tell())
    except (OSError, ValueError):
        return default


class UartCaptureSource(DiskFileSource):
    """A raw UART capture (.bin): the byte stream the board sent, decoded in large chunks.

    Chunks are cut after their last 0x00 so no packet straddles two decodes; the result is
    the same as one :class:`protocol.uart.Deframer` fed the whole file and flushed.
    """

    def __init__(self, path: str | os.PathLike[str], chunk_bytes: int = UART_CHUNK_BYTES) -> None:
        self.path = Path(path)
        self.description = f"UART capture {self.path}"
        self._size = check_readable(self.path)
        self.chunk_bytes = max(1, int(chunk_bytes))
        self.frames = 0
        self.link_errors = 0

    def batches(self, max_frames: int = 65536) -> Iterator[SourceBatch]:
        max_frames = max(1, int(max_frames))
        self._pos = self.frames = self.link_errors = 0
        nan = math.nan
        with self._open_binary() as f:
            carry = b""
            discarding = False  # inside a runaway packet already reported
            while True:
                try:
                    chunk = f.read(self.chunk_bytes)
                except OSError as exc:
                    yield self._read_failed(exc)
                    return
                if not chunk:
                    break
                data, carry = carry + chunk, b""
                if discarding:
                    z = data.find(b"\0")
                    if z < 0:
                        self._pos = f.tell()
                        continue
                    data, discarding = data[z + 1 :], False
                cut = data.rfind(b"\0") + 1
                frames, errors = deframe_bytes(data[:cut], nan) if cut else (empty_frames(), [])
                rest = data[cut:]
                if len(rest) > MAX_BODY:  # no delimiter within MAX_BODY: report, skip to next
                    errors += deframe_bytes(rest[: MAX_BODY + 1], nan)[1]
                    discarding = True
                else:
                    carry = rest
                self._pos = f.tell() - len(carry)
                yield from self._emit(frames, errors, max_frames)
            if carry:  # the last packet never got its 0x00
                yield from self._emit(empty_frames(), deframe_bytes(carry, nan)[1], max_frames)
            self._pos = self._size
        self._check_unchanged(self.frames)

    def _emit(
        self, frames: np.ndarray, errors: list[LinkError], max_frames: int
    ) -> Iterator[SourceBatch]:
        self.frames += len(frames)
        self.link_errors += len(errors)
        if not len(frames):
            if errors:
                yield SourceBatch(empty_frames(), errors)
            return
        for b in range(0, len(frames), max_frames):
            # link errors of a chunk ride with its first batch: they carry no position
            yield SourceBatch(frames[b : b + max_frames], errors if b == 0 else [])


__all__ = ["CanLogReaderSource", "UartCaptureSource"]
