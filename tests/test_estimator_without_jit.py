"""The estimator's unit tests once more as plain Python, with ``NUMBA_DISABLE_JIT=1``.

Issue 26 asks that the estimator's tests also pass uncompiled: numba's typing can hide a
bug that Python would raise (an integer division, an out-of-range index numba does not
check, a dtype it coerces), and the plain-Python run is what a reader steps through in a
debugger. The flag must be set before numba is first imported, so the tests run in a
child pytest. The scenario tests of the joint filter are left out: uncompiled, one
emulated run takes minutes.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).parent
UNIT_TESTS = (
    "test_model.py",
    "test_estimator_units.py",
    "test_isolation_carry.py",
    "test_estimator_batching.py",
)
PROBE = """
import numba
import sys
sys.exit(0 if numba.config.DISABLE_JIT else 3)
"""


def _env() -> dict[str, str]:
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    env.pop("PYTEST_XDIST_WORKER", None)
    return env


def test_numba_sees_the_flag() -> None:
    """The child's numba really runs uncompiled (else the run below proves nothing)."""
    probe = subprocess.run([sys.executable, "-c", PROBE], env=_env(), check=False)
    assert probe.returncode == 0


def test_the_unit_tests_pass_uncompiled() -> None:
    files = [str(TESTS / name) for name in UNIT_TESTS]
    for f in files:
        assert Path(f).is_file(), f"{f} moved: keep this list true"
    run = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:xdist", "-p", "no:cacheprovider", *files],
        env=_env(),
        cwd=TESTS.parent,
        capture_output=True,
        text=True,
        check=False,
    )
    tail = run.stdout[-3000:] + run.stderr[-2000:]
    assert run.returncode == 0, tail
    passed = re.search(r"(\d+) passed", run.stdout)
    assert passed is not None, tail
    assert int(passed.group(1)) >= 40, tail  # the four files hold 49 tests today
