"""A replay's start overlaps its parts: the log is read while the pipeline is built, the
estimator's kernels load while the command opens its files, and the joint filter's loop
lets the reading and the writer run while it computes (issue 29; the read-ahead's tests
are in test_prefetch.py). Behaviour only; the times are in benchmarks/replay_process.py."""

from __future__ import annotations

import subprocess
import sys
import textwrap


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


def test_a_replay_that_fails_at_once_ends_only_after_the_kernels_loading(tmp_path) -> None:
    """A mistake in the arguments ends the command before the background load is done; the
    command waits for it, so the interpreter never shuts down under a thread inside numba's
    loader (`python -m bench replay missing.log` ended by SIGSEGV instead of exit 2). In a
    fresh interpreter: in this one the kernels are loaded already."""
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
        print("threads:", sorted(t.name for t in threading.enumerate()))
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    error, threads = done.stdout.splitlines()
    assert error.startswith("error: log file not found") and "missing.log" in error
    assert threads == "threads: ['MainThread']"
