"""One opener for every replayable log, chosen by the file's extension (case-insensitive).

devices/ registers the device formats below; the bench registers its own MCAP recordings
(``bench/__init__``), so devices/ never imports the bench. A format names its opener as
``"module:callable"`` (as a packaging entry point does), imported only when a log of that
format is opened: a replay pays for its own reader alone, and importing ``bench`` does not
import the MCAP reader.

Operator mistakes (missing file, unknown extension, not a regular file) are one
:class:`BenchError` line here, before any reader runs.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from devices.paths import check_readable, unknown_extension

if TYPE_CHECKING:
    from devices.base import FileSource


class LogFormat(NamedTuple):
    name: str
    """What a fleet report calls the format ("candump", "blf", "mcap", ...)."""
    opener: str
    """``"module:callable"``; ``callable(path, **kwargs)`` returns the FileSource of a
    readable regular file of the format."""


_FORMATS: dict[str, LogFormat] = {}


def register_format(suffix: str, name: str, opener: str) -> None:
    """Make :func:`open_log` open ``*suffix`` files with ``opener`` ("module:callable")."""
    _FORMATS[suffix.lower()] = LogFormat(name, opener)


def log_formats() -> dict[str, str]:
    """Every registered extension and its format's name, in registration order."""
    return {suffix: fmt.name for suffix, fmt in _FORMATS.items()}


def open_log(path: str | os.PathLike[str], **kwargs: Any) -> FileSource:
    """The FileSource for ``path`` by extension; ``kwargs`` go to the source (e.g.
    ``chunk_bytes`` for candump and UART logs, ``batching`` for MCAP)."""
    p = Path(path)
    fmt = _FORMATS.get(p.suffix.lower())
    if fmt is None:
        raise unknown_extension(p, tuple(_FORMATS))
    check_readable(p)
    module, _, name = fmt.opener.partition(":")
    source: FileSource = getattr(importlib.import_module(module), name)(p, **kwargs)
    return source


register_format(".log", "candump", "devices.candump:CandumpFileSource")
for _suffix in (".asc", ".blf", ".trc", ".csv"):
    register_format(_suffix, _suffix[1:], "devices.files:CanLogReaderSource")
register_format(".bin", "uart", "devices.files:UartCaptureSource")

__all__ = ["LogFormat", "log_formats", "open_log", "register_format"]
