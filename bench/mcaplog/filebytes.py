"""An MCAP file's bytes, read with ordinary reads instead of a memory mapping.

Why not mmap: a mapped file that shrinks while it is read (a copy still being written,
a network share, a truncate) kills the process with SIGBUS at the first page past the new
end, with no message and no chance to say what was replayed. :class:`FileBytes` slices
like the mapping did (``buf[a:b]`` is ``bytes``, ``buf[i]`` an int, ``len(buf)`` the size
when opened), each slice one ``os.pread``; a read that comes back short is
:class:`FileChanged`, an error naming the file. The reader reads a chunk at a time, so
this costs one copy per chunk, as slicing the mapping did.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import overload

from bench.mcaplog.structure import McapReadError

_MAX_READ = 1 << 30
"""Bytes per pread (Linux returns at most ~2 GiB per call)."""


class FileChanged(McapReadError):
    """The file is shorter than when it was opened: it changed while it was read."""


class FileBytes:
    """Read-only, sliceable bytes of an open file (see the module docstring)."""

    def __init__(self, fd: int, size: int, path: Path) -> None:
        self.fd, self.size, self.path = fd, size, path

    def __len__(self) -> int:
        return self.size

    @overload
    def __getitem__(self, key: int) -> int: ...
    @overload
    def __getitem__(self, key: slice) -> bytes: ...
    def __getitem__(self, key: int | slice) -> bytes | int:
        if isinstance(key, slice):
            start, stop, step = key.indices(self.size)
            if step != 1:
                raise ValueError("FileBytes slices have step 1")
            return self.read(start, stop - start)
        index = key + self.size if key < 0 else key
        if not 0 <= index < self.size:
            raise IndexError(key)
        return self.read(index, 1)[0]

    def read(self, offset: int, n: int) -> bytes:
        """``n`` bytes at ``offset`` (``n <= 0``: none); FileChanged when the file ends first."""
        if n <= 0:
            return b""
        parts = []
        got = 0
        while got < n:
            part = os.pread(self.fd, min(n - got, _MAX_READ), offset + got)
            if not part:
                break
            parts.append(part)
            got += len(part)
        if got < n:
            raise self.changed(offset + got)
        return parts[0] if len(parts) == 1 else b"".join(parts)

    def changed(self, at: int) -> FileChanged:
        try:
            now = f"{os.fstat(self.fd).st_size} bytes now"
        except OSError:
            now = "its size unknown now"
        return FileChanged(
            f"{self.path}: the file changed while it was read: it ends before byte {at}, it was "
            f"{self.size} bytes when opened ({now}); a file still being written or copied "
            "must be read once it is complete"
        )
