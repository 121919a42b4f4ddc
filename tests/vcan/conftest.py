"""Tests on a real SocketCAN bus (marker ``vcan``): they need a Linux kernel with vcan0 up.

Elsewhere (this project's CI machine, a laptop without CAN) they are skipped with the
reason; ``tools/vcan-vm`` boots a VM where they run (``.ci/run`` does exactly that, with
BENCH_VCAN_REQUIRED=1: there, anything missing is a failure, not a skip). On a
machine that has vcan0, parallel test workers would share the bus: the first of these tests
in a worker takes a lock file, so only one worker at a time is on vcan0.
"""

from __future__ import annotations

import fcntl
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.vcan.support import REQUIRED, VM_HINT, preload, socketcan_missing

HERE = Path(__file__).parent
LOCK = Path("/tmp/gradient-bench-vcan0.lock")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    ours = [item for item in items if HERE in Path(str(item.fspath)).parents]
    if not ours:
        return
    reason = socketcan_missing()
    if reason is not None and REQUIRED:
        raise pytest.UsageError(f"vcan tests required (BENCH_VCAN_REQUIRED=1), but {reason}")
    if reason is not None:
        for item in ours:
            item.add_marker(pytest.mark.skip(reason=f"{reason}; {VM_HINT}"))


@pytest.fixture(scope="session", autouse=True)
def _one_session_on_vcan0() -> Iterator[None]:
    """Held from the first test here to the end of this process's session."""
    with LOCK.open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        preload()
        yield
