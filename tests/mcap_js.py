"""Runs tests/js/check_mcap.mjs (@mcap/core, the reader Foxglove uses) on our MCAP files.

Installing the npm packages is part of the test setup: when tests/js/node_modules is
missing, the fixture runs ``npm ci`` (the lockfile pins every version). Without node/npm,
or when the install fails, the tests are skipped with the reason on a developer machine,
but FAIL under CI (env CI set), so the conformance check can never silently vanish there.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

JS_DIR = Path(__file__).parent / "js"
CHECKER = JS_DIR / "check_mcap.mjs"
_REQUIRED = ("@mcap/core", "@mcap/nodejs", "@mcap/support")


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def _unavailable(reason: str) -> None:
    if in_ci():
        pytest.fail(f"MCAP conformance check cannot run in CI: {reason}", pytrace=False)
    pytest.skip(f"MCAP conformance check (@mcap/core) not run: {reason}")


def _installed() -> bool:
    return all((JS_DIR / "node_modules" / name / "package.json").is_file() for name in _REQUIRED)


@dataclass(frozen=True)
class McapJs:
    node: str

    def check(
        self, path: Path, *, stream_only: bool = False, expect_ok: bool = True
    ) -> dict[str, Any]:
        """The checker's JSON report for ``path``; asserts a clean exit unless told not to."""
        cmd = [self.node, str(CHECKER), *(["--stream"] if stream_only else []), str(path)]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=JS_DIR)
        try:
            report = json.loads(proc.stdout)
        except json.JSONDecodeError:
            raise AssertionError(
                f"check_mcap.mjs gave no JSON (exit {proc.returncode}): {proc.stderr[-2000:]}"
            ) from None
        if expect_ok:
            assert proc.returncode == 0, f"@mcap/core check failed: {report.get('errors')}"
            assert report["errors"] == []
        return report


def install() -> McapJs:
    """Locate node and npm, install the checker's packages if needed (idempotent)."""
    node = shutil.which("node")
    npm = shutil.which("npm")
    if node is None or npm is None:
        _unavailable("node/npm not found on PATH (Node.js 20+ is required)")
    assert node is not None and npm is not None
    if not _installed():
        verb = "ci" if (JS_DIR / "package-lock.json").is_file() else "install"
        cmd = [npm, verb, "--no-audit", "--no-fund", "--ignore-scripts"]
        try:
            proc = subprocess.run(cmd, cwd=JS_DIR, capture_output=True, text=True, timeout=600)
        except (OSError, subprocess.TimeoutExpired) as exc:
            _unavailable(f"{' '.join(cmd)} failed: {exc}")
        if proc.returncode != 0 or not _installed():
            err = proc.stderr.strip()[-800:]
            _unavailable(f"{' '.join(cmd)} failed (exit {proc.returncode}): {err}")
    return McapJs(node)
