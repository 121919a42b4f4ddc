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
