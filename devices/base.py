"""The one abstraction every frame source implements (python-can's BusABC style).

A source hands out :class:`SourceBatch` es: frames in the numpy FRAME_DTYPE layout plus
whatever went wrong on the way (UART link errors, unparsable log lines, disconnects),
so the pipeline treats a live bus, a serial port and a log file alike.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from protocol.frames import empty_frames
from protocol.records import LinkError


class SourceNotice(NamedTuple):
    """Something a source reports that is not a frame: a bad log line, a disconnect, a reconnect.

    kind is one of: "parse_error", "truncated", "disconnect", "reconnect", "info".
    """

    t: float
    kind: str
    detail: str


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
