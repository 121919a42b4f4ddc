"""Session set-up shared by every test module."""

from __future__ import annotations

import os
import signal
import tempfile
from collections.abc import Iterator

import pytest
from hypothesis import settings

# No wall-time bound in any test: hypothesis's default 200 ms deadline per example is one
# (test_protocol_uart failed a 5-byte example at 273 ms on a fresh clone's suite at load 10).
# Loaded here, before the test modules' @settings take it as their parent.
settings.register_profile("bench", deadline=None)
settings.load_profile("bench")


def pytest_configure() -> None:
    """Compile (or load from numba's on-disk cache) the joint filter's kernel once per test
    process before any test runs: tests that start the bench in a subprocess and wait for
    its first output must not spend their timeout on the compiler. And no operator's
    defaults (bench.defaults: BENCH_INTERFACE ..., ~/.config/bench/config.toml) reach the
    tests, nor the commands they start."""
    from bench.defaults import ENV

    for name in ENV.values():
        os.environ.pop(name, None)
    os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="bench-tests-xdg-")

    from bench.fusion.estimator import warm_up

    warm_up()


_ENDING_SIGNALS = tuple(
    getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)
)


@pytest.fixture(autouse=True)
def _signal_handlers_put_back() -> Iterator[None]:
    """A command run in-process that was signalled stays deaf to repeats on purpose (its
    process is about to exit); in a test process that deafness must not reach the next
    test (CI: SIGINT ignored in one worker hung the read-ahead Ctrl-C test and both
    SIGINT clean-stop tests, whose child inherited SIG_IGN)."""
    saved = {s: signal.getsignal(s) for s in _ENDING_SIGNALS}
    yield
    for s, handler in saved.items():
        if handler is not None and signal.getsignal(s) is not handler:
            signal.signal(s, handler)
