"""Reproducible performance evidence for the bench: ``python -m benchmarks [--quick]``.

Every figure is measured on the machine that runs the command, next to an anchor measured
in the same run (python-can's bare ``LogReader`` iteration of the same file, the ``mcap``
package's own reader), so ratios compare like with like. Each measurement runs in its own
Python process (:mod:`benchmarks._worker`), so one cannot skew another through leftover
threads, caches or garbage. See docs/BENCHMARKS.md for what each figure means.

Modules: :mod:`benchmarks.common` (figures, machine, test data), :mod:`benchmarks.replay`
(log replay vs python-can), :mod:`benchmarks.fusion` (fusion core),
:mod:`benchmarks.mcap_write` (MCAP logging), :mod:`benchmarks.live` (virtual-bus rate and
latency), :mod:`benchmarks.soak` (the 10-minute soak).
"""
