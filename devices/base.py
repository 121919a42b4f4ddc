"""The one abstraction every frame source implements (python-can's BusABC style).

A source hands out :class:`SourceBatch` es: frames in the numpy FRAME_DTYPE layout plus
whatever went wrong on the way (UART link errors, unparsable log lines, disconnects),
so the pipeline treats a live bus, a serial port and a log file alike.
"""

from __future__ import annotations

import math
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, NamedTuple, TypeVar

import numpy as np

from devices.errors import BenchError
from devices.paths import cannot_read
from protocol.frames import empty_frames
from protocol.records import LinkError


class SourceNotice(NamedTuple):
    """Something a source reports that is not a frame: a bad log line, a disconnect, a reconnect.

    kind is one of: "parse_error", "truncated", "disconnect", "reconnect", "overflow", "info".
    ``count`` is how many frames an "overflow" notice stands for (frames the kernel dropped
    at a full socket receive buffer since the previous notice); 0 for the other kinds.
    """

    t: float
    kind: str
    detail: str
    count: int = 0  # type: ignore[assignment]  # a field, shadowing tuple.count (unused here)


@dataclass(slots=True)
class SourceBatch:
    frames: np.ndarray = field(default_factory=empty_frames)  # FRAME_DTYPE, arrival order
    link_errors: list[LinkError] = field(default_factory=list)
    notices: list[SourceNotice] = field(default_factory=list)

    def __bool__(self) -> bool:
        return bool(len(self.frames) or self.link_errors or self.notices)


class LiveSource(ABC):
    """A source that is read in real time (bus, serial port, in-process emulator)."""

    description: str = "live source"

    @abstractmethod
    def read(self, timeout: float) -> SourceBatch:
        """Block up to ``timeout`` s for the first frame, then return it with every frame
        already waiting (up to a burst limit). An empty batch means nothing arrived."""

    @abstractmethod
    def close(self) -> None: ...

    def __enter__(self) -> LiveSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_Device = TypeVar("_Device")


class Reconnector:
    """When a live source whose device went away tries to reopen it (backoff).

    After :meth:`dropped` the first attempt is due ``initial`` s later; each failed attempt
    doubles the wait, up to ``maximum``; a successful one resets it.
    """

    def __init__(self, initial: float, maximum: float) -> None:
        self.initial = initial
        self.maximum = maximum
        self._backoff = initial
        self._next_attempt = 0.0

    def dropped(self) -> None:
        self._backoff = self.initial
        self._next_attempt = time.monotonic() + self._backoff

    def attempt(self, timeout: float, reopen: Callable[[], _Device]) -> _Device | None:
        """Sleep until the next attempt is due (at most ``timeout``), then ``reopen()``: the
        reopened device, or None when no attempt was due yet or it raised a BenchError."""
        wait = self._next_attempt - time.monotonic()
        if wait > 0:
            time.sleep(min(wait, max(0.0, timeout)))
            if wait > timeout:
                return None
        try:
            device = reopen()
        except BenchError:
            self._backoff = min(self._backoff * 2, self.maximum)
            self._next_attempt = time.monotonic() + self._backoff
            return None
        self._backoff = self.initial
        return device


class FileSource(ABC):
    """A recorded log read as a sequence of batches in file order."""

    description: str = "log file"

    @abstractmethod
    def batches(self, max_frames: int = 65536) -> Iterator[SourceBatch]: ...

    def size_bytes(self) -> int:
        """Total size for a progress bar (0 when unknown)."""
        return 0

    def position(self) -> int:
        """Bytes consumed so far, for a progress bar."""
        return 0

    def close(self) -> None:  # noqa: B027 - optional hook
        pass


class DiskFileSource(FileSource):
    """A log file on disk, read front to back: its size when opened and the bytes consumed
    so far (``_size``, ``_pos``) drive the progress bar."""

    path: Path
    _size = 0
    _pos = 0

    def size_bytes(self) -> int:
        return self._size

    def position(self) -> int:
        return self._pos

    def _open_binary(self) -> BinaryIO:
        try:
            return self.path.open("rb")
        except OSError as exc:
            raise cannot_read(self.path, exc) from exc

    def _check_unchanged(self, frames: int) -> None:
        """At the end of the file: BenchError when its size is no longer what it was when
        opened (a copy still being written, a truncate): what was read is of neither
        version, so the replay stops instead of passing it off as the file."""
        try:
            size = self.path.stat().st_size
        except OSError as exc:
            now = f"now {exc.strerror or exc}"
        else:
            if size == self._size:
                return
            now = f"{size} bytes now"
        raise BenchError(
            f"{self.path}: the file changed while it was read ({self._size} bytes when "
            f"opened, {now}): replay stopped after {frames} frames; a file still being "
            "written or copied must be read once it is complete"
        )

    def _read_failed(self, exc: OSError) -> SourceBatch:
        """The last batch of a stream whose read failed part way."""
        detail = f"{self.path}: read failed after {self._pos} bytes: {exc}"
        return SourceBatch(notices=[SourceNotice(math.nan, "truncated", detail)])
