"""A command's files before anything opens, and outputs that appear only when complete.

One rule for every command: every output is compared with every input and every other
output (the same file by name, hard link or symlink; two outputs naming one file that
does not exist yet) before anything is opened, and a clash is one line naming both
(:func:`check_clashes`). Inputs must be regular files: a FIFO or a device given as a log,
config, scenario or plan would be waited on forever (:func:`regular_file_problem`).

Outputs are written under a temporary name beside the real one and renamed into place
when complete (:class:`StagedFile`), so a run that fails part way never leaves half a file
under the real name (and never truncates the file that was there). ``-`` (stdout), a
device (``/dev/null``) and a FIFO are written directly: a rename would replace them.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import stat
from collections.abc import Iterator, Sequence
from pathlib import Path

from devices.errors import BenchError

STDOUT = "-"

Named = tuple[str, "str | os.PathLike[str] | None"]
"""(role, path): ``("--csv", "out.csv")``, ``("the input log", "run.mcap")``; a None path
(an option not given) is left out."""

_staged_ids = itertools.count(1)


def file_kind(mode: int) -> str:
    """'a FIFO', 'a character device', ... for a file that is not a regular file."""
    for test, name in (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def cannot_read(path: Path, exc: OSError) -> BenchError:
    return BenchError(f"cannot read log {path}: {exc.strerror or exc}")


def check_readable(path: Path) -> int:
    """Size of a readable regular file, else a one-line BenchError naming it.

    A FIFO, a device (/dev/zero) or a socket is refused: a replay reads ahead, seeks and
    reports progress against the size, and /dev/zero never ends."""
    try:
        if path.is_dir():
            raise BenchError(f"cannot read log {path}: is a directory")
        st = path.stat()
        if not stat.S_ISREG(st.st_mode):
            raise BenchError(
                f"cannot read log {path}: not a regular file ({file_kind(st.st_mode)}); "
                "copy the recording to a file first"
            )
        size = st.st_size
        with path.open("rb"):
            pass
    except FileNotFoundError as exc:
        raise BenchError(f"log file not found: {path}") from exc
    except OSError as exc:
        raise cannot_read(path, exc) from exc
    return size


def unknown_extension(path: Path, known: tuple[str, ...]) -> BenchError:
    """The one-line error for a log whose extension no reader handles."""
    suffix = path.suffix.lower()
    return BenchError(
        f"cannot read log {path}: unknown extension {suffix or '(none)'!r} ({' '.join(known)})"
    )


def regular_file_problem(path: str | os.PathLike[str]) -> str:
    """Why ``path`` cannot be read as a file ("" when it can: a regular file, through any
    symlinks). Asked before opening: opening a FIFO for reading waits for a writer."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "no such file"
    except OSError as exc:
        return exc.strerror or str(exc)
    if stat.S_ISREG(st.st_mode):
        return ""
    if stat.S_ISDIR(st.st_mode):
        return "it is a folder"
    return f"not a regular file ({file_kind(st.st_mode)}); copy it to a file first"


def _identity(path: str) -> tuple[str, object]:
    """What makes two names one file: device and inode of what exists (symlinks followed,
    hard links alike), else the resolved path a new file would be created at."""
    try:
        st = os.stat(path)
    except OSError:
        return "path", os.path.realpath(path)
    return "inode", (st.st_dev, st.st_ino)


def _writes_through(path: str) -> bool:
    """A device or FIFO: any number of outputs may share it (``/dev/null``)."""
    try:
        st = os.stat(path)
    except OSError:
        return False
    return not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode))


def check_clashes(inputs: Sequence[Named], outputs: Sequence[Named]) -> None:
    """BenchError naming both when an output is one of the inputs or two outputs are one
    file. Call it before anything is opened: then nothing has been touched."""
    ins = [(role, os.fspath(p)) for role, p in inputs if p is not None and os.fspath(p) != STDOUT]
    outs = [(role, os.fspath(p)) for role, p in outputs if p is not None]
    seen: dict[tuple[str, object], tuple[str, str, bool]] = {}  # -> role, path, an input
    for role, p in ins:
        seen.setdefault(_identity(p), (role, p, True))
    for role, p in outs:
        key = ("stdout", None) if p == STDOUT else _identity(p)
        earlier = seen.get(key)
        if earlier is not None and not (key[0] == "inode" and _writes_through(p)):
            other_role, other, is_input = earlier
            if is_input:
                same = "" if os.path.abspath(p) == os.path.abspath(other) else ", the same file"
                raise BenchError(
                    f"{role} {p} is the {other_role} ({other}{same}): writing it would destroy "
                    f"the {other_role}; give another {role} (nothing was written)"
                )
            where = "both write to stdout" if p == STDOUT else "name the same file"
            raise BenchError(
                f"{other_role} {other} and {role} {p} {where}: give each output a path "
                "of its own (nothing was written)"
            )
        seen.setdefault(key, (role, p, False))


def stageable(path: str | os.PathLike[str]) -> bool:
    """Whether an output is written under a temporary name first: not stdout, a device or
    a FIFO (writing is all they take; a rename would replace the device node)."""
    p = os.fspath(path)
    return p != STDOUT and not _writes_through(p)


class StagedFile:
    """One output file written as ``.NAME.partial-PID-N.SUFFIX`` in the folder of the real
    name (a symlink's target for a symlink), renamed over the real name by :meth:`commit`.
    The suffix stays last, so a writer that chooses the format by it still can."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)  # the name the operator gave (for messages)
        final = self.path
        if final.is_symlink():  # write where the link points, keep the link
            final = Path(os.path.realpath(final))
        self.final = final
        self.temp = final.with_name(
            f".{final.stem}.partial-{os.getpid()}-{next(_staged_ids)}{final.suffix}"
        )
        self._identity: tuple[int, int] | None = None
        self.done = False

    def create(self) -> Path:
        """Create the (empty) temporary file and note its identity (see :meth:`problem`);
        the writer then opens it by name. OSError when the folder does not take it."""
        fd = os.open(self.temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        try:
            st = os.fstat(fd)
            self._identity = (st.st_dev, st.st_ino)
        finally:
            os.close(fd)
        return self.temp

    def problem(self) -> str:
        """Why committing cannot give the operator this output ("" while it can): the file
        being written was deleted or replaced, or the real name became a folder."""
        if self._identity is not None:
            try:
                st = os.stat(self.temp)
            except FileNotFoundError:
                return "the file being written was deleted during the run"
            except OSError:
                st = None
            if st is not None and (st.st_dev, st.st_ino) != self._identity:
                return "the file being written was replaced by another during the run"
        if self.final.is_dir() and not self.final.is_symlink():
            return f"{self.path} became a folder during the run"
        return ""

    def commit(self) -> None:
        """Flush the complete file to the disk and rename it over the real name; OSError
        (named after the real name) when that cannot be done, the temporary file removed."""
        if self.done:
            return
        self.done = True
        try:
            if why := self.problem():
                raise OSError(why)
            fd = os.open(self.temp, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(self.temp, self.final)
        except OSError as exc:
            self._remove()
            raise OSError(exc.errno or 0, exc.strerror or str(exc), str(self.path)) from None

    def discard(self) -> None:
        """Remove the temporary file: the real name keeps what it had."""
        self.done = True
        self._remove()

    def _remove(self) -> None:
        with contextlib.suppress(OSError):
            os.unlink(self.temp)


@contextlib.contextmanager
def staged(path: str | os.PathLike[str]) -> Iterator[Path]:
    """The path to write ``path``'s content to: a temporary name renamed into place when the
    block ends normally, removed when it raises (``path`` itself for stdout or a device)."""
    if not stageable(path):
        yield Path(path)
        return
    out = StagedFile(path)
    try:
        yield out.create()
    except BaseException:
        out.discard()
        raise
    out.commit()


def write_file(path: str | os.PathLike[str], data: bytes | str) -> None:
    """``data`` written to ``path`` whole or not at all (text as UTF-8)."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    with staged(path) as target:
        target.write_bytes(raw)


__all__ = [
    "STDOUT",
    "StagedFile",
    "cannot_read",
    "check_clashes",
    "check_readable",
    "file_kind",
    "regular_file_problem",
    "stageable",
    "staged",
    "unknown_extension",
    "write_file",
]
