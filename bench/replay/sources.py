"""Open any replayable log: the device formats of :mod:`devices.files` and the bench's own MCAP.

MCAP is the bench's format (its reader knows the bench's topics and schemas), so it is opened
here rather than in devices/, which never imports the bench.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from bench.errors import BenchError
from devices.base import FileSource
from devices.bus import one_line
from devices.files import SUFFIXES as DEVICE_SUFFIXES
from devices.files import check_readable, open_log, unknown_extension

MCAP_SUFFIX = ".mcap"
SUFFIXES = (*DEVICE_SUFFIXES, MCAP_SUFFIX)


def open_replay(path: str | os.PathLike[str], **kwargs: Any) -> FileSource:
    """The FileSource for ``path`` by extension (case-insensitive); ``kwargs`` go to the
    source (e.g. ``chunk_bytes`` for device logs, ``batching`` for MCAP)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise unknown_extension(p, SUFFIXES)
    if suffix != MCAP_SUFFIX:
        return open_log(p, **kwargs)
    check_readable(p)
    from bench.mcaplog.source import McapFrameSource  # the MCAP reader only when needed

    try:
        return McapFrameSource(p, **kwargs)
    except BenchError:
        raise
    except Exception as exc:
        raise BenchError(f"cannot read {p}: {one_line(exc)}") from exc
