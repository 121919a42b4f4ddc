"""Child processes of the bench: a fresh interpreter running one module, over a socket pair.

One mechanism for every child (the live TUI's engine, the MCAP writer process):
``python -m MODULE FD`` with this source tree importable, talking through a
multiprocessing ``Connection`` on a socket pair. The child sees end-of-file when the parent
is gone, however it went (kill -9 included), and finishes its work then. A fresh
interpreter rather than multiprocessing: a daemonic multiprocessing child may not start
children of its own, and the engine starts the writer.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
from multiprocessing.connection import Connection
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
"""The source tree holding protocol/, devices/ and bench/ (importable also when not installed)."""


def start_child(
    module: str, *, own_session: bool = False, quiet: bool = False
) -> tuple[Connection, subprocess.Popen[bytes]]:
    """Start ``python -m module FD``; returns our end of the connection and the process.

    ``own_session``: a session of its own, so a terminal's Ctrl-C or hang-up reaches only the
    parent. ``quiet``: no stdin/stdout/stderr (the parent reports the child's errors)."""
    ours, theirs = socket.socketpair()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    streams = (
        {"stdin": subprocess.DEVNULL, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
        if quiet
        else {"stdin": subprocess.DEVNULL}
    )
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", module, str(theirs.fileno())],
            pass_fds=(theirs.fileno(),),
            env=env,
            start_new_session=own_session,
            **streams,  # type: ignore[call-overload]  # stdout/stderr only: no text= overload
        )
    except BaseException:
        ours.close()
        raise
    finally:
        theirs.close()
    return Connection(ours.detach()), proc


def parent_connection(argv: list[str]) -> Connection:
    """In the child: the connection to the parent (the descriptor :func:`start_child` passed)."""
    return Connection(int(argv[1]))


def wait_child(proc: subprocess.Popen[bytes], timeout: float) -> int | None:
    """The child's exit code after waiting up to ``timeout`` s (None: still running)."""
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout)
    return proc.returncode


def end_child(proc: subprocess.Popen[bytes], grace_s: float) -> None:
    """Wait ``grace_s`` for the child to end by itself, then terminate, then kill it."""
    if wait_child(proc, grace_s) is not None:
        return
    for end in (proc.terminate, proc.kill):
        end()
        if wait_child(proc, 5.0) is not None:
            return
