"""python-can's text log readers (.asc .trc .csv) with every line accounted for.

python-can's ASCReader skips any line it does not recognise (a negative time, a garbled
channel, a cut line), its TRCReader drops lines it cannot split, and any value it cannot
convert (a garbled hex ID) raises out of the reader's generator, which ends the file there.
Here python-can still does the parsing, but it reads through a :class:`LineLedger`: a file
object that numbers the lines it hands out and notes which of them produced a message. A
frame line that produced none is a counted ``parse_error`` notice naming the line; after a
reader raises, the same reader is iterated again from the next line (the format is one
record per line), so the rest of the file is read.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable, Iterator
from typing import Any, BinaryIO

import can
from can.io.trc import TRCFileVersion

from devices.base import SourceNotice
from devices.candump import UTF8_BOM

MAX_LINE_BYTES = 4096
"""A longer "line" is not a log record (binary noise without newlines): counted, skipped."""

# the lines are judged here: python-can's warnings about them would be stray stderr lines
logging.getLogger("can.io").addHandler(logging.NullHandler())

_ASC_NOT_FRAMES = re.compile(
    r"""(?ix) ^ (
        // .*                                           # comment
      | date \s .* | base \s .*                          # header
      | (no \s+)? internal \s+ events \s+ logged .*
      | (begin | end) \s+ triggerblock .*
      | \d+ \. \d+ \s+ (
            start \s+ of \s+ measurement .*
          | \d+ \s+ statistic: .*                        # bus statistics event
          | (?! canfd (\s|$)) [a-z] [\w:.-]+ (\s .*)?     # an event on no CAN channel (a name)
        )
    ) $"""
)
_ASC_DIRECTION = re.compile(r"(?i)\s(rx|tx)\s")
_ASC_DATA = re.compile(r"(?i)\sd\s+\d{1,2}(\s+[0-9a-f]{2})+(\s|$)")
"""A data frame's ``d <dlc> <bytes>``: a frame line even when its channel or direction is
garbled (python-can then skips it, so it must be counted)."""
_TRC_NOT_FRAMES_V1 = frozenset({"Warng", "Error"})
_TRC_NOT_FRAMES_V2 = frozenset({"ST", "EC", "ER", "EV"})


def asc_frame_line(reader: Any, line: str) -> bool:
    """Whether an ASC line is a CAN frame (not a header, comment, trigger or bus event)."""
    if _ASC_DIRECTION.search(line) or _ASC_DATA.search(line):
        return True
    return not _ASC_NOT_FRAMES.match(line)


def trc_frame_line(reader: Any, line: str) -> bool:
    """Whether a TRC line is a CAN frame (not a comment, bus info, status or error event)."""
    if line.startswith(";"):
        return False
    cols = line.split()
    version = getattr(reader, "file_version", TRCFileVersion.UNKNOWN)
    if version >= TRCFileVersion.V2_0:
        at = getattr(reader, "columns", {}).get("T")
        return at is None or at >= len(cols) or cols[at] not in _TRC_NOT_FRAMES_V2
    if version in (TRCFileVersion.V1_1, TRCFileVersion.V1_3):
        at = 2 if version == TRCFileVersion.V1_1 else 3
        return at >= len(cols) or cols[at] not in _TRC_NOT_FRAMES_V1
    return len(cols) < 3 or cols[2] != "FFFFFFFF"  # 1.0: bus information lines


CSV_HEADER = "timestamp,arbitration_id,extended,remote,error,dlc,data"


def csv_frame_line(reader: Any, line: str) -> bool:
    return line != CSV_HEADER


class TextFormat:
    """How to read one text format: its python-can reader, which lines are frames, and the
    line that lets the reader start again mid-file (its header step consumes one line)."""

    def __init__(
        self,
        reader: type[can.io.generic.MessageReader],
        frame_line: Callable[[Any, str], bool],
        resume_preamble: str | None,
    ) -> None:
        self.reader, self.frame_line, self.resume_preamble = reader, frame_line, resume_preamble


TEXT_FORMATS = {
    ".asc": TextFormat(can.ASCReader, asc_frame_line, "no internal events logged"),
    ".trc": TextFormat(can.TRCReader, trc_frame_line, None),
    ".csv": TextFormat(can.CSVReader, csv_frame_line, CSV_HEADER),
}


def _snippet(text: str) -> str:
    text = text.strip()
    return repr(text if len(text) <= 60 else text[:57] + "...")


class LineLedger:
    """A text file for python-can readers that remembers the lines not yet matched by a
    message. Bytes are decoded as UTF-8 with replacement, so a bad byte spoils one line only."""

    def __init__(self, f: BinaryIO) -> None:
        self._f = f
        self.lineno = 0
        self._pending: list[tuple[int, str]] = []  # non-blank lines not yet judged
        self._preamble: list[str] = []
        self._ahead: bytes | None = None
        self.overlong: list[int] = []

    # -- the file interface python-can's text readers use
    def __iter__(self) -> LineLedger:
        return self

    def __next__(self) -> str:
        if self._preamble:
            return self._preamble.pop()
        raw = self._read_line()
        if not raw:
            raise StopIteration
        self.lineno += 1
        if self.lineno == 1:
            raw = raw.removeprefix(UTF8_BOM)  # an editor's byte-order mark
        if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):
            self.overlong.append(self.lineno)
            while raw and not raw.endswith(b"\n"):  # skip to the end of this "line"
                raw = self._f.readline(1 << 20)
            return "\n"
        text = raw.decode("utf-8", "replace")
        if text.endswith("\r\n"):  # as a text file in universal-newline mode reads it
            text = text[:-2] + "\n"
        if text.strip():
            self._pending.append((self.lineno, text))
        return text

    def readline(self) -> str:
        try:
            return next(self)
        except StopIteration:
            return ""

    def close(self) -> None:
        self._f.close()

    def tell(self) -> int:
        return self._f.tell() - (len(self._ahead) if self._ahead else 0)

    # -- accounting
    def _read_line(self) -> bytes:
        if self._ahead is not None:
            raw, self._ahead = self._ahead, None
            return raw
        return self._f.readline(MAX_LINE_BYTES + 1)

    def at_eof(self) -> bool:
        if self._ahead is None:
            self._ahead = self._f.readline(MAX_LINE_BYTES + 1)
        return not self._ahead

    def push_preamble(self, line: str | None) -> None:
        if line is not None:
            self._preamble.append(line + "\n")

    def take_last(self) -> tuple[int, str] | None:
        """The line just handed out, if it is still unjudged (it produced a message, or
        the reader raised on it)."""
        if self._pending and self._pending[-1][0] == self.lineno:
            return self._pending.pop()
        return None

    def has_unread(self) -> bool:
        return bool(self._pending or self.overlong)

    def unread(self) -> list[tuple[int, str]]:
        """The lines handed out and not matched to a message since the last call."""
        out, self._pending = self._pending, []
        return out


def read_text_log(
    fmt: TextFormat, f: BinaryIO, path: object, **reader_kwargs: Any
) -> Iterator[can.Message | SourceNotice]:
    """Messages of a text log in file order, with a ``parse_error`` notice for every frame
    line python-can skipped or raised on (at the place it was found)."""
    ledger = LineLedger(f)
    # python-can's text readers take an open file too; their hint names paths only
    reader = fmt.reader(ledger, **reader_kwargs)  # type: ignore[arg-type]
    name = fmt.reader.__name__

    def error(lineno: int, why: str, text: str) -> SourceNotice:
        detail = f"{path}: line {lineno}: {why}: {_snippet(text)}"
        return SourceNotice(math.nan, "parse_error", detail)

    def judged(raised: tuple[int, str] | None, exc: Exception | None) -> Iterator[SourceNotice]:
        for lineno, text in ledger.unread():
            if fmt.frame_line(reader, text.strip()):
                yield error(lineno, f"skipped by python-can's {name}", text)
        if raised is not None:
            yield error(raised[0], f"{name} failed: {type(exc).__name__}: {exc}", raised[1])
        while ledger.overlong:
            lineno = ledger.overlong.pop(0)
            detail = f"{path}: line {lineno}: longer than {MAX_LINE_BYTES} bytes"
            yield SourceNotice(math.nan, "parse_error", detail)

    try:
        while True:
            start = ledger.lineno
            try:
                for msg in reader:
                    ledger.take_last()  # the line that produced ``msg``
                    if ledger.has_unread():
                        yield from judged(None, None)
                    yield msg
            except Exception as exc:  # python-can raises anything on bad text
                # a raise on a line that holds nothing (a blank line) loses no frame
                yield from judged(ledger.take_last(), exc)
                if ledger.lineno == start or ledger.at_eof():
                    return
                ledger.push_preamble(fmt.resume_preamble)
                continue
            yield from judged(None, None)
            return
    finally:
        ledger.close()


__all__ = ["MAX_LINE_BYTES", "TEXT_FORMATS", "LineLedger", "TextFormat", "read_text_log"]
