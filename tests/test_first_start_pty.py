"""A first start in a terminal (issue 28: 39 s of blank terminal while numba compiled the
estimator's kernel, the calibration line only after ``q``; a first ``bench replay`` silent
for 41 s). An empty numba cache (``NUMBA_CACHE_DIR`` pointing at a fresh folder) makes it a
first start: the screen must come up and say the estimator is being prepared while the
kernel is not in the cache yet, with the calibration line before the screen. Each test ends
the command (its whole process group) as soon as it has seen what it looks for, so the
compile it started costs only those seconds.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import pty
import re
import select
import signal
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

from tests.helpers import bench

ROOT = Path(__file__).resolve().parent.parent
ALT_SCREEN = b"\x1b[?1049h"
SCENARIO = """
seed = 3
duration_s = 20.0
sample_rate_hz = 100
[[channels]]
[[channels]]
[[channels]]
"""
PREPARING = re.compile(r"preparing the estimator|[⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏] estimator \d+ s")
"""The estimator column's headline, or the status bar's (Textual redraws only what changed:
the column's text may come in pieces between cursor moves, the status bar's in one)."""
ESCAPES = re.compile(rb"\x1b\[[0-9;?<>=$]*[A-Za-z~]|\x1b\][^\x07]*\x07|\x1b[=>()][A-Za-z0-9]?")


def first_start_env(tmp_path: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba-cache")  # empty: nothing compiled yet
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), env.get("PYTHONPATH")) if p)
    env["TERM"] = "xterm-256color"
    env.pop("TEXTUAL", None)
    return env


def kernel_cached(env: dict[str, str]) -> bool:
    """numba's index of the estimator's kernel is in the cache folder (it compiled)."""
    return any(Path(env["NUMBA_CACHE_DIR"]).rglob("joint_kernel.run-*.nbi"))


def text_of(screen: bytes) -> str:
    """What a terminal shows of a byte stream, roughly: escape sequences dropped."""
    return ESCAPES.sub(b"", screen).decode("utf-8", "replace")


def test_first_bench_demo_shows_the_screen_and_says_the_estimator_is_being_prepared(
    tmp_path: Path,
) -> None:
    env = first_start_env(tmp_path)
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO, encoding="utf-8")
    argv = [sys.executable, "-m", "bench", "demo", "--scenario", str(scenario), "--no-log"]
    pid, fd = pty.fork()
    if pid == 0:  # the child: the command, in a terminal of 100x30
        os.chdir(tmp_path)
        os.execvpe(argv[0], argv, env)
    fcntl.ioctl(fd, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))
    out = b""
    started = time.monotonic()
    preparing_at: float | None = None  # when the screen first said so
    cached_then = None  # was the kernel in numba's cache at that moment?
    cached_at: float | None = None  # when the compile had finished
    try:
        deadline = started + 240.0  # a liveness bound, not a speed requirement
        while time.monotonic() < deadline:
            ready, _, _ = select.select([fd], [], [], 0.2)
            if ready:
                try:
                    chunk = os.read(fd, 65536)
                except OSError:
                    break
                if not chunk:
                    break
                out += chunk
            now = time.monotonic() - started
            if cached_at is None and kernel_cached(env):
                cached_at = now
            screen = text_of(out.split(ALT_SCREEN, 1)[1]) if ALT_SCREEN in out else ""
            if preparing_at is None and PREPARING.search(screen):
                preparing_at, cached_then = now, kernel_cached(env)
            done = preparing_at is not None and "calibration: scenario s.toml" in screen
            if done or cached_at is not None:
                break
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(pid, signal.SIGKILL)  # the screen and the engine: the compile ends here
        os.waitpid(pid, 0)
        os.close(fd)
    assert ALT_SCREEN in out, text_of(out)[-2000:]
    before, screen_bytes = out.split(ALT_SCREEN, 1)
    screen = text_of(screen_bytes)
    assert "bench: calibration: scenario s.toml as built" in text_of(before)  # before the run
    assert preparing_at is not None, (
        f"the kernel was compiled after {cached_at} s, and the screen never said it was "
        f"being prepared: {screen[-3000:]}"
    )
    assert cached_then is False  # on screen while the kernel was not in numba's cache yet
    assert "calibration: scenario s.toml" in screen  # and said on the screen too


def test_first_bench_replay_says_it_compiles_before_it_does(tmp_path: Path) -> None:
    env = first_start_env(tmp_path)
    scenario = tmp_path / "s.toml"
    scenario.write_text(SCENARIO, encoding="utf-8")
    log = tmp_path / "run.log"
    made = bench("emulate", str(scenario), "--out", str(log), env=env)
    assert made.returncode == 0, made.stderr
    assert not kernel_cached(env)  # writing an emulator log needs no estimator
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench", "replay", str(log), "-q"],
        env=env,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        start_new_session=True,
    )
    lines: list[str] = []
    try:
        assert proc.stderr is not None
        for raw in proc.stderr:
            lines.append(raw.decode())
            if "preparing the estimator" in lines[-1]:
                break
        cached = kernel_cached(env)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert any(line.startswith("bench: preparing the estimator (first start") for line in lines)
    assert not cached


def test_a_warm_start_says_nothing_of_it() -> None:
    """With the kernel in the cache (conftest compiled it for this process's cache), no
    notice: it is for first starts only."""
    from bench.pipeline.warmup import prepare

    said: list[str] = []
    assert prepare(said.append) is None and said == []
