"""Session set-up shared by every test module."""

from __future__ import annotations


def pytest_configure() -> None:
    """Compile (or load from numba's on-disk cache) the joint filter's kernel once per test
    process before any test runs: tests that start the bench in a subprocess and wait for
    its first output must not spend their timeout on the compiler."""
    from bench.fusion.joint import warm_up

    warm_up()
