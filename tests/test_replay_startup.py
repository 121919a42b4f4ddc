"""A replay's start overlaps its parts: the log is read while the pipeline is built, its
first frames are decoded and fused while the estimator's kernels load (test_replay_stages.py),
and the joint filter's loop lets the reading and the writer run while it computes (issue 29;
the read-ahead's tests are in test_prefetch.py). Behaviour only; the times are in
benchmarks/replay_process.py."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_the_joint_filter_loop_lets_other_threads_run() -> None:
    from bench.fusion import joint_kernel

    assert joint_kernel.run.targetoptions.get("nogil") is True


def test_a_replay_that_fails_at_once_leaves_no_thread_and_never_loads_numba(tmp_path) -> None:
    """A mistake in the arguments ends the command before any kernel is loaded: no thread is
    left for the interpreter to shut down under (a load thread inside numba's loader made
    `python -m bench replay missing.log` end by SIGSEGV instead of exit 2), and numba is
    not even imported. In a fresh interpreter: in this one the kernels are loaded already."""
    code = textwrap.dedent(
        f"""
        import argparse, threading
        from bench.commands import replay
        from bench.errors import BenchError
        args = argparse.Namespace(
            input={str(tmp_path / "missing.log")!r}, config=None, plan=None, csv=None,
            parquet=None, mcap=None, compare=False, smooth=False, quiet=True,
        )
        try:
            replay.run(args)
        except BenchError as exc:
            print("error:", exc)
        import sys
        print("threads:", sorted(t.name for t in threading.enumerate()), "numba" in sys.modules)
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    error, threads = done.stdout.splitlines()
    assert error.startswith("error: log file not found") and "missing.log" in error
    assert threads == "threads: ['MainThread'] False"


def test_the_pipeline_and_the_replay_import_without_numba() -> None:
    """The first stage needs no compiled kernel: importing the pipeline and the replay
    must not import numba (its import and cache load are what the first frames must not
    wait for; the estimator imports it when it is built)."""
    code = "import sys, bench.replay.run, bench.pipeline.steps; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False"]


def _replay_in_a_fresh_interpreter(log: str, *args: str) -> tuple[list[str], str]:
    """``bench replay LOG ARGS`` run by bench.cli.main in a fresh interpreter: the rich
    modules it imported, and its stderr."""
    code = textwrap.dedent(
        f"""
        import sys
        from bench.cli import main
        code = main(["replay", {log!r}, *{list(args)!r}])
        print(code, sorted(m for m in sys.modules if m == "rich" or m.startswith("rich.")))
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    exit_code, modules = done.stdout.split(" ", 1)
    assert exit_code == "0", done.stderr
    return eval(modules), done.stderr  # a printed list of str


def test_a_quiet_replay_never_imports_rich(tmp_path) -> None:
    """``bench replay -q`` shows nothing (no progress bar, no summary table), so it does
    not pay rich's import (about 45 ms of its start, issue 29); without ``-q`` the summary
    is rich's table."""
    log = tmp_path / "board.log"
    log.write_text("(0.000000) can0 123#0011\n(0.001000) can0 123#2233\n")
    modules, err = _replay_in_a_fresh_interpreter(str(log), "-q")
    assert modules == [] and err == ""
    modules, err = _replay_in_a_fresh_interpreter(str(log))
    assert "rich.table" in modules and "unknown IDs" in err


def test_a_quiet_replay_still_prints_its_warnings(tmp_path) -> None:
    """A warning is shown under ``-q`` too (rich imported for it, its markup escaped)."""
    log = tmp_path / "board.log"
    log.write_text("(0.000000) can0 123#0011\nnot [bold]a frame\n(0.002000) can0 123#2233\n")
    modules, err = _replay_in_a_fresh_interpreter(str(log), "-q")
    assert "rich.console" in modules
    (line,) = err.splitlines()
    assert line.startswith("warning: parse_error: line 2: not a candump line")
    assert line.endswith(": 'not [bold]a frame'")  # as written: no markup taken from a log


def _threads_after_a_quiet_replay(log: str, env: dict[str, str]) -> int:
    code = textwrap.dedent(
        f"""
        import os
        from bench.cli import main
        assert main(["replay", {log!r}, "-q"]) == 0
        print(len(os.listdir("/proc/self/task")), os.environ.get("OPENBLAS_NUM_THREADS"))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True
    )
    count, setting = done.stdout.split()
    assert setting == env.get("OPENBLAS_NUM_THREADS", "1")
    return int(count)


def test_a_replay_starts_no_openblas_threads_unless_told(tmp_path) -> None:
    """numpy's OpenBLAS starts a thread per further core at import; a replay asks for none
    (OPENBLAS_NUM_THREADS=1 before numpy is imported), and an operator's own setting
    stands: with 2 the process has exactly one thread more."""
    import os

    import pytest

    if not os.path.isdir("/proc/self/task") or (os.cpu_count() or 1) < 2:
        pytest.skip("counts threads in /proc; OpenBLAS makes none on one core")
    log = tmp_path / "board.log"
    log.write_text("(0.000000) can0 123#0011\n(0.001000) can0 123#2233\n")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    ours = _threads_after_a_quiet_replay(str(log), env)
    told = _threads_after_a_quiet_replay(str(log), {**env, "OPENBLAS_NUM_THREADS": "2"})
    assert told == ours + 1
