"""A replay's start overlaps its parts: the log is read while the pipeline is built, the
estimator's kernels load while the command opens its files, and the joint filter's loop
lets the reading and the writer run while it computes (issue 29). Behaviour only; the
times are in benchmarks/replay_process.py."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
from collections.abc import Iterator

from bench.replay.prefetch import ReadAhead


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

    def items() -> Iterator[int]:
        try:
            i = 0
            while True:
                yield i
                i += 1
        finally:
            closed.set()

    ahead = ReadAhead(items(), depth=2)
    ahead.close()  # e.g. the pipeline's construction failed
    assert closed.is_set()
    assert not any(t.name == "read-ahead" and t.is_alive() for t in threading.enumerate())


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


def test_kernels_in_the_cache_load_in_the_background_and_others_are_left_to_prepare() -> None:
    code = textwrap.dedent(
        """
        from bench.pipeline.warmup import kernel_is_ready, load_in_background
        ready = kernel_is_ready()
        load_in_background().join()
        from bench.fusion import isolation, joint_kernel
        loaded = [bool(k.overloads) for k in (joint_kernel.run, *isolation.KERNELS)]
        print(ready, all(loaded), any(loaded))
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    ready = out[0] == "True"
    # cached: every kernel loaded; not cached: none compiled here (prepare() says so first)
    assert out[1:] == (["True", "True"] if ready else ["False", "False"])


def test_the_joint_filter_loop_lets_other_threads_run() -> None:
    from bench.fusion import joint_kernel

    assert joint_kernel.run.targetoptions.get("nogil") is True
