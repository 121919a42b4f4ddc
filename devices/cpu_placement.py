"""Where the live path runs: one CPU of its own for the threads that share the GIL.

Why: the virtual board, acquisition and processing of a live run hand work to each other
every few hundred microseconds, and only one of them can hold the GIL at a time, so a second
CPU gains them nothing. Spread over two CPUs (the scheduler's choice) each hand-off may wake a
thread on the other CPU, cache-cold, behind whatever runs there: the MCAP writer process, the
TUI's screen process. Measured on 2 cores at 1 kHz x 3 channels: latency p99 2.0-2.8 ms
without the TUI and 3.4-3.9 ms with it; with the live threads on one CPU and the writer and
screen on the other, 0.3-0.4 ms and 0.4-0.8 ms (docs/BENCHMARKS.md).

``BENCH_LIVE_CPU`` chooses: ``auto`` (default; the highest CPU this process may use, when it
may use two or more), a CPU number, or ``off`` (no pinning: the scheduler decides). A second
bench on the same machine should be given another CPU.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading

from devices.errors import BenchError

LIVE_CPU_ENV = "BENCH_LIVE_CPU"
log = logging.getLogger("bench.cpu")

_allowed: frozenset[int] | None = None


def allowed_cpus() -> frozenset[int]:
    """The CPUs this process may use, as its first caller saw them (empty where the OS
    cannot say): read once, so that a thread pinned later does not narrow it."""
    global _allowed
    if _allowed is None:
        try:
            _allowed = frozenset(os.sched_getaffinity(0))
        except (AttributeError, OSError):  # not Linux: no thread placement
            _allowed = frozenset()
    return _allowed


def live_cpus() -> frozenset[int] | None:
    """The CPU the live threads go to, or None for no placement. A bad ``BENCH_LIVE_CPU``
    is a one-line :class:`BenchError` (call this before starting threads)."""
    allowed = allowed_cpus()
    raw = os.environ.get(LIVE_CPU_ENV, "auto").strip().lower() or "auto"
    if raw == "off" or (raw == "auto" and len(allowed) < 2):
        return None
    if raw == "auto":
        return frozenset({max(allowed)})
    try:
        cpu = int(raw)
    except ValueError:
        cpu = -1
    if cpu not in allowed:
        choices = ", ".join(str(c) for c in sorted(allowed)) or "none"
        raise BenchError(
            f"{LIVE_CPU_ENV}={raw!r}: expected auto, off or a CPU this process may use ({choices})"
        )
    return frozenset({cpu})


def live_cpu_label() -> str:
    """The live CPU as a run's metadata and the benchmarks write it: "1", or "any"."""
    return ",".join(str(c) for c in sorted(live_cpus() or ())) or "any"


def other_cpus() -> frozenset[int] | None:
    """The CPUs for everything else (writer, screen), or None when nothing is placed."""
    live = live_cpus()
    rest = allowed_cpus() - live if live is not None else frozenset()
    return rest or None


Placement = tuple[int, frozenset[int]] | None
"""What :func:`pin_thread` changed: (thread id, CPUs it had), for :func:`restore_thread`."""


def pin_thread(cpus: frozenset[int] | None) -> Placement:
    """Put the calling thread (and the threads and processes it starts later) on ``cpus``.
    None: leave it alone. Failure (a cpuset changed under us) leaves it unplaced."""
    if not cpus:
        return None
    try:
        before = frozenset(os.sched_getaffinity(0))
        os.sched_setaffinity(0, cpus)
    except (AttributeError, OSError) as exc:
        log.debug("thread placement on CPUs %s failed: %s", sorted(cpus), exc)
        return None
    return threading.get_native_id(), before


def restore_thread(placement: Placement) -> None:
    """Undo :func:`pin_thread` (from any thread)."""
    if placement is not None:
        with contextlib.suppress(AttributeError, OSError):
            os.sched_setaffinity(placement[0], placement[1])


def yield_cpu() -> None:
    """The lowest CPU priority for the calling thread and what it starts later (call it
    first thing in a helper process): SCHED_IDLE on Linux, preempted by any normal thread
    that wakes; nice 10 elsewhere."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        with contextlib.suppress(AttributeError, OSError):
            os.nice(10)
