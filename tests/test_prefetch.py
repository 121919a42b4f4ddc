"""Read-ahead keeps order, hands the reader's exception to the consumer, and stops early;
a ReadAhead reads from its construction on (a replay reads while its pipeline is built)."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from bench.replay.prefetch import ReadAhead, prefetch


def test_items_come_in_order() -> None:
    assert list(prefetch(range(1000), depth=3)) == list(range(1000))


def test_reader_exception_reaches_the_consumer_after_the_items_before_it() -> None:
    def items() -> Iterator[int]:
        yield 1
        yield 2
        raise ValueError("truncated log")

    got = []
    with pytest.raises(ValueError, match="truncated log"):
        for x in prefetch(items()):
            got.append(x)
    assert got == [1, 2]


def _endless(closed: threading.Event) -> Iterator[int]:
    """0, 1, 2, ... until closed; then ``closed`` is set."""
    try:
        i = 0
        while True:
            yield i
            i += 1
    finally:
        closed.set()


def _readers() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.name == "read-ahead" and t.is_alive()}


def _assert_ended(readers: set[threading.Thread]) -> None:
    """Each of these reader threads ends once it has seen the stop (only the test's own:
    another test's reader may still be winding down in this process)."""
    for t in readers:
        t.join(timeout=30)
        assert not t.is_alive()


def test_stopping_early_closes_the_reader() -> None:
    closed = threading.Event()
    others = _readers()
    it = prefetch(_endless(closed), depth=2)
    assert [next(it) for _ in range(5)] == [0, 1, 2, 3, 4]
    mine = _readers() - others
    assert len(mine) == 1
    it.close()  # what a `break` out of a for loop does
    assert closed.wait(timeout=30)  # the close reached the reader (a loaded machine is slow)
    _assert_ended(mine)


def test_read_ahead_reads_before_it_is_iterated_and_keeps_order() -> None:
    produced = threading.Event()

    def items() -> Iterator[int]:
        produced.set()
        yield from range(10)

    ahead = ReadAhead(items(), depth=4)
    assert produced.wait(timeout=30)  # nobody iterated yet: the reader thread did it
    assert list(ahead) == list(range(10))


def test_closing_a_read_ahead_never_iterated_stops_its_reader() -> None:
    closed = threading.Event()
    ahead = ReadAhead(_endless(closed), depth=2)
    ahead.close()  # e.g. the pipeline's construction failed
    assert closed.wait(timeout=30)
    _assert_ended({ahead._reader})


def test_a_read_ahead_hands_the_reader_failure_over() -> None:
    def items() -> Iterator[int]:
        yield 1
        raise OSError("input/output error")

    got = []
    ahead = ReadAhead(items())
    try:
        for x in ahead:
            got.append(x)
    except OSError as exc:
        assert str(exc) == "input/output error"
    else:
        raise AssertionError("the failure was lost")
    assert got == [1]
