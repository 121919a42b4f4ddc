"""Shared pieces of the benchmarks: figures, the machine, test data, timing, memory.

A :class:`Figure` is one row of the table: a measured value, what it is measured against
(its *anchor*, e.g. python-can's bare LogReader iteration of the same file) and, where the
issue sets one, a target. The target may be on the value itself or on value / anchor.
"""

from __future__ import annotations

import gc
import math
import os
import platform
import subprocess
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

BOARD_RATE_HZ = 1000
"""The fastest rate the ACB-3 samples at (ICD): every live figure is taken at 1 kHz x 3 ch."""


# ------------------------------------------------------------------------------- figures
@dataclass
class Figure:
    """One row of the table.

    ``target`` applies to ``value`` (``on="value"``) or to ``value / anchor``
    (``on="ratio"``); ``op`` is ">=" or "<=". Without a target the row is informational.
    """

    key: str
    label: str
    value: float | None
    unit: str
    target: float | None = None
    op: str = ">="
    on: str = "value"  # "value" or "ratio"
    anchor: float | None = None
    anchor_label: str = ""
    detail: str = ""
    error: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def ratio(self) -> float | None:
        if self.value is None or not self.anchor:
            return None
        return self.value / self.anchor

    @property
    def status(self) -> str:
        if (
            self.error
            or self.value is None
            or (isinstance(self.value, float) and math.isnan(self.value))
        ):
            return "ERROR"
        if self.target is None:
            return "INFO"
        x = self.ratio if self.on == "ratio" else self.value
        if x is None:
            return "ERROR"
        ok = x >= self.target if self.op == ">=" else x <= self.target
        return "PASS" if ok else "MISS"

    def target_text(self) -> str:
        if self.target is None:
            return "-"
        if self.on == "ratio":
            return f"{self.op} {self.target:g}x anchor"
        return f"{self.op} {fmt_value(self.target, self.unit)}"

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["ratio"] = self.ratio
        d["status"] = self.status
        d["target_text"] = self.target_text()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Figure:
        names = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in names})


def fmt_value(v: float | None, unit: str) -> str:
    """Human form of a figure: 1.23 M frames/s, 45.6 k, 2.31 ms."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if unit.endswith("/s"):
        if abs(v) >= 1e6:
            return f"{v / 1e6:.2f} M {unit}"
        if abs(v) >= 1e3:
            return f"{v / 1e3:.1f} k {unit}"
        return f"{v:.0f} {unit}"
    if unit == "ms":
        return f"{v:.2f} ms"
    if unit == "MB":
        return f"{v:.1f} MB"
    return f"{v:g} {unit}".strip()


# ------------------------------------------------------------------------------- machine
def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(module: str) -> str:
    try:
        from importlib.metadata import version

        return version(module)
    except Exception:
        return "?"


def git_commit() -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
        return out.stdout.strip() or "?"
    except (OSError, subprocess.SubprocessError):
        return "?"


def machine_info() -> dict[str, Any]:
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        usable = os.cpu_count() or 0
    try:
        load = os.getloadavg()
    except OSError:  # pragma: no cover
        load = (math.nan, math.nan, math.nan)
    try:
        mem_kb = int(
            next(
                line.split()[1]
                for line in Path("/proc/meminfo").read_text().splitlines()
                if line.startswith("MemTotal:")
            )
        )
    except (OSError, StopIteration, ValueError):
        mem_kb = 0
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": usable,
        "memory_gb": round(mem_kb / 1024 / 1024, 1),
        "os": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "numpy": np.__version__,
        "python-can": _version("python-can"),
        "mcap": _version("mcap"),
        "textual": _version("textual"),
        "loadavg_at_start": [round(x, 2) for x in load],
        "commit": git_commit(),
        "live_cpu": live_cpu_text(),
    }


def live_cpu_text() -> str:
    """Where the live path's threads run (devices.cpu_placement, BENCH_LIVE_CPU)."""
    from devices.cpu_placement import LIVE_CPU_ENV, live_cpu_label

    label = live_cpu_label()
    setting = os.environ.get(LIVE_CPU_ENV, "auto")
    where = "unplaced" if label == "any" else f"on CPU {label}"
    return f"live path {where} ({LIVE_CPU_ENV}={setting})"


# ------------------------------------------------------------------------------- test data
def board_scenario(
    duration_s: float, *, seed: int = 8, faults: Iterable[dict[str, Any]] = ()
) -> dict[str, Any]:
    """A scenario dict for a 1 kHz board on a moving train (valid frames, realistic values)."""
    return {
        "seed": seed,
        "duration_s": float(duration_s),
        "sample_rate_hz": BOARD_RATE_HZ,
        "description": "benchmark board: 1 kHz x 3 channels",
        "track": [
            {"length_m": 2000.0, "gradient_permil": 8.0},
            {"length_m": 3000.0, "gradient_permil": -12.0},
            {"length_m": 1e6, "gradient_permil": 3.0},
        ],
        "train": [
            {"duration_s": 20.0, "accel_mps2": 0.5},
            {"duration_s": max(1.0, float(duration_s)), "accel_mps2": 0.0},
        ],
        "channels": [
            {"angle_deg": 30.0, "noise_mps2": 0.004},
            {"angle_deg": 0.0, "noise_mps2": 0.004},
            {"angle_deg": -30.0, "noise_mps2": 0.004},
        ],
        "faults": list(faults),
    }


def simulation(duration_s: float, **kwargs: Any) -> Any:
    from devices.emulator import scenario_from_dict, simulate

    return simulate(scenario_from_dict(board_scenario(duration_s, **kwargs), "benchmark"))


def board_frame_rate() -> float:
    """Frames per second the 1 kHz board sends (3 ADC + status + SPEED_REF)."""
    sim = simulation(2.0)
    return len(sim.frames) / 2.0


def frames_for(n_frames: int) -> np.ndarray:
    """At least ``n_frames`` frames of the 1 kHz board, cut to exactly ``n_frames``."""
    duration = math.ceil(n_frames / (board_frame_rate() * 0.995)) + 1
    frames = simulation(duration).frames
    if len(frames) < n_frames:  # pragma: no cover - the margin above covers it
        raise RuntimeError(f"simulation gave {len(frames)} frames, wanted {n_frames}")
    return frames[:n_frames]


# ------------------------------------------------------------------------------- timing
def timed(fn: Callable[[], Any], repeat: int = 3) -> tuple[float, Any]:
    """Best (shortest) wall time of ``repeat`` calls, and the last call's result.

    The best of several runs is the usual estimate of what the code costs when the machine
    is not interrupting it; every figure and its anchor are timed the same way."""
    best = math.inf
    result = None
    for _ in range(max(1, repeat)):
        gc.collect()
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def timed_pair(
    a: Callable[[], Any], b: Callable[[], Any], repeat: int = 3
) -> tuple[tuple[float, Any], tuple[float, Any]]:
    """Best wall time of ``a`` and of ``b``, run alternately (a b a b ...), so that a figure
    and its anchor see the same machine load even on a shared machine."""
    best = [math.inf, math.inf]
    result: list[Any] = [None, None]
    for _ in range(max(1, repeat)):
        for i, fn in enumerate((a, b)):
            gc.collect()
            t0 = time.perf_counter()
            result[i] = fn()
            best[i] = min(best[i], time.perf_counter() - t0)
    return (best[0], result[0]), (best[1], result[1])


def warm_file(path: Path) -> None:
    """Read a file once so that every contender finds it in the page cache."""
    with open(path, "rb") as f:
        while f.read(16 << 20):
            pass


def rss_mb() -> float:
    """Resident set size of this process (Linux /proc), MB."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError):
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
