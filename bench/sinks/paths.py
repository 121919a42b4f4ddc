"""Output paths checked before a run starts, and write failures told in one line.

A run that cannot write its CSV should say so before it opens a bus or an MCAP file, not
after a traceback halfway through; a write that fails later (a full disk) is a one-line
error naming the file (``bench: error: out.csv: cannot write: No space left on device``).
"""

from __future__ import annotations

import os
from pathlib import Path

from bench.errors import BenchError

STDOUT = "-"


def check_output_file(path: str | Path, what: str = "output") -> None:
    """BenchError unless ``path`` can be created or replaced as a regular file: its folder
    exists and is writable, and ``path`` is not a folder. ``-`` (stdout) and character
    devices (``/dev/null``, ``/dev/full``) pass: a device's failures are write failures."""
    if str(path) == STDOUT:
        return
    p = Path(path)
    if p.is_dir():
        raise BenchError(f"{p}: cannot write the {what}: it is a folder, give a file name")
    if p.exists():
        if not p.is_file():
            return  # a device or FIFO: writing tells
        if not os.access(p, os.W_OK):
            raise BenchError(f"{p}: cannot write the {what}: permission denied")
        return
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise BenchError(f"{p}: cannot write the {what}: folder {parent} does not exist")
    if not parent.is_dir():
        raise BenchError(f"{p}: cannot write the {what}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BenchError(f"{p}: cannot write the {what}: folder {parent} is not writable")


def check_output_dir(path: str | Path, what: str = "output") -> None:
    """BenchError unless ``path`` is a folder or can be created as one."""
    p = Path(path)
    if p.exists():
        if not p.is_dir():
            raise BenchError(f"{p}: cannot write the {what} there: it is not a folder")
        if not os.access(p, os.W_OK | os.X_OK):
            raise BenchError(f"{p}: cannot write the {what} there: permission denied")
        return
    for parent in p.parents:
        if parent.exists():
            if not parent.is_dir():
                raise BenchError(f"{p}: cannot create the folder: {parent} is not a folder")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise BenchError(f"{p}: cannot create the folder: {parent} is not writable")
            return


def describe_os_error(exc: OSError) -> str:
    """``No space left on device`` rather than pyarrow's or Python's longer forms."""
    if exc.errno:
        return os.strerror(exc.errno)
    return exc.strerror or str(exc)


def write_error(path: str | Path, exc: OSError) -> BenchError:
    """The one-line error for a failed write to ``path``."""
    return BenchError(f"{path}: cannot write: {describe_os_error(exc)}")
