"""Read ahead of the pipeline: a file source's batches come from a thread of their own.

Reading a log is mostly decompression, CRC and array parsing, which release the GIL, so on a
second core it overlaps with the pipeline's own numpy work instead of adding to it. The
order of batches is kept, an exception in the reader is raised in the consumer, and a
consumer that stops early stops the reader.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")

_END = object()
JOIN_TIMEOUT_S = 2.0
"""How long the consumer's exit waits for the reader to notice it should stop."""


class _Failed:
    def __init__(self, exc: BaseException) -> None:
        self.exc = exc


class ReadAhead(Generic[T]):
    """``items`` read in a background thread from construction on, at most ``depth`` ahead:
    a replay starts reading while its pipeline is still being built (the estimator's
    kernels loading). Iterate it once; :meth:`close` stops the reader (iterating to the end,
    or leaving the loop, does too)."""

    def __init__(self, items: Iterable[T], depth: int = 2) -> None:
        self._q: queue.Queue[object] = queue.Queue(maxsize=max(1, depth))
        self._stop = threading.Event()
        self._items = items
        self._reader = threading.Thread(target=self._run, name="read-ahead", daemon=True)
        self._reader.start()

    def _put(self, item: object) -> bool:
        while not self._stop.is_set():
            try:
                self._q.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        it = iter(self._items)
        try:
            for item in it:
                if not self._put(item):
                    return
            self._put(_END)
        except BaseException as exc:  # handed to the consumer, never lost in the thread
            self._put(_Failed(exc))
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()

    def __iter__(self) -> Iterator[T]:
        try:
            while True:
                try:  # in slices: a Ctrl-C delivered to the reader thread must still get through
                    item = self._q.get(timeout=0.1)
                except queue.Empty:
                    continue
                if item is _END:
                    return
                if isinstance(item, _Failed):
                    raise item.exc
                yield item  # type: ignore[misc]  # neither _END nor _Failed: one of the items
        finally:
            self.close()

    def close(self) -> None:
        self._stop.set()
        # a reader stuck inside one read (a pipe that never writes, a hung network file)
        # must not hold up Ctrl-C or the end of a replay: it is a daemon thread, left to die
        self._reader.join(timeout=JOIN_TIMEOUT_S)


def prefetch(items: Iterable[T], depth: int = 2) -> Iterator[T]:
    """Iterate ``items`` in a background thread, at most ``depth`` items ahead (the thread
    starts with the iteration)."""
    yield from ReadAhead(items, depth)
