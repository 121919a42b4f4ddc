"""Latency after toggling the recording: ``r`` twice, as an operator stops and restarts a log.

``python -m benchmarks.rec_toggle [--before 3] [--after 5] [--toggles 2]`` runs the live path
as `bench demo` / `bench tui` do (virtual board at 1 kHz x 3 channels on a private virtual
channel, CanBusSource, LiveRunner, the TUI's :class:`~bench.live.session.Recorder` in front
of the live MCAP sink in its writer process) and presses ``r`` twice ``toggles`` times: stop
(detach, then close the file off the processing thread, as the App's worker does) and start
(a new file, a new writer process). It prints the frame-to-result latency p50/p99/max over
the seconds before the first toggle and over the seconds after each start.

Why: starting a recording used to open the new file *under the Recorder's lock*, and opening
it starts a writer process and waits for its first reply (0.3-1.2 s); the processing thread,
which writes every step through that lock, waited the whole time. The results of that second
arrived hundreds of ms late, and the TUI's p99 (over the last 5 000 results) showed it for as
long as they stayed in its window: 264-396 ms for more than 10 s in `bench demo`.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.sinks.base import Sink
from benchmarks.common import Figure, board_scenario


class TimedLatency(Sink):
    """A sink after the Recorder: (wall time, frame-to-result latency) of every result that
    a frame made, so the latency can be cut into windows afterwards."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._wall: list[float] = []
        self._lat: list[float] = []

    def write(self, step: Any) -> None:
        now = time.time()
        res = step.results
        if not len(res) or step.batch is None:
            return
        lat = (now - res["t"]) * 1000.0
        with self._lock:
            self._wall.extend([now] * len(res))
            self._lat.extend(lat.tolist())

    def deliveries(self, start: float, end: float) -> tuple[int, float]:
        """Results delivered between wall times ``start`` and ``end``, and the longest time
        in that span without a delivery (the span itself when there was none)."""
        with self._lock:
            wall = np.array(self._wall)
        inside = np.unique(wall[(wall >= start) & (wall <= end)])
        edges = np.concatenate([[start], inside, [end]])
        return int(np.count_nonzero((wall >= start) & (wall <= end))), float(np.diff(edges).max())

    def window(self, start: float, end: float) -> np.ndarray:
        """Latencies (ms) of the results delivered between wall times ``start`` and ``end``."""
        with self._lock:
            wall = np.array(self._wall)
            lat = np.array(self._lat)
        sel = (wall >= start) & (wall < end) & np.isfinite(lat)
        return lat[sel]


@dataclass
class ToggleRun:
    before_s: float
    after_s: float
    toggles: int
    before: tuple[float, float, float] = (math.nan, math.nan, math.nan)  # p50, p99, max ms
    after: list[tuple[float, float, float]] = field(default_factory=list)
    start_s: list[float] = field(default_factory=list)  # how long each start took
    during: list[int] = field(default_factory=list)  # results delivered while it ran
    gap_s: list[float] = field(default_factory=list)  # longest wait for a result meanwhile
    files: int = 0
    dropped: int = 0
    errors: list[str] = field(default_factory=list)

    @property
    def worst_after_p99(self) -> float:
        return max((p99 for _, p99, _ in self.after), default=math.nan)

    def report(self) -> str:
        def fmt(f: tuple[float, float, float]) -> str:
            return f"p50 {f[0]:.2f} ms  p99 {f[1]:.2f} ms  max {f[2]:.1f} ms"

        lines = [
            f"recording toggled {self.toggles}x at 1 kHz x 3 ch (live MCAP writer process)",
            f"  {self.before_s:g} s before the first toggle: {fmt(self.before)}",
        ]
        for k, (f, took) in enumerate(zip(self.after, self.start_s, strict=True)):
            lines.append(f"  {self.after_s:g} s after start {k + 1} (took {took:.2f} s): {fmt(f)}")
            lines.append(
                f"    while it started: {self.during[k]} results delivered, "
                f"longest wait {1000 * self.gap_s[k]:.0f} ms"
            )
        lines.append(f"  files {self.files}, runner drops {self.dropped}")
        lines += [f"  error: {e}" for e in self.errors]
        return "\n".join(lines)


def _stats(lat: np.ndarray) -> tuple[float, float, float]:
    if not len(lat):
        return (math.nan, math.nan, math.nan)
    p50, p99 = np.percentile(lat, (50, 99)).tolist()
    return (p50, p99, float(lat.max()))


def run(
    before_s: float = 3.0, after_s: float = 5.0, toggles: int = 2, workdir: str | None = None
) -> ToggleRun:
    import can

    from bench.config import Config
    from bench.live.runner import LiveRunner
    from bench.live.session import Recorder
    from bench.live.setup import recording_sink_class
    from devices.bus import CanBusSource
    from devices.emulator import scenario_from_dict, simulate, start_virtual_board

    out = ToggleRun(before_s, after_s, toggles)
    total = before_s + toggles * (after_s + 1.0) + 3.0
    sim = simulate(scenario_from_dict(board_scenario(total), "toggle"))
    config = Config(sample_rate_hz=sim.scenario.sample_rate_hz)
    channel = f"bench-toggle-{os.getpid()}"
    source = CanBusSource(bus=can.Bus(interface="virtual", channel=channel), owns_bus=True)
    lat = TimedLatency()
    with tempfile.TemporaryDirectory(prefix="bench-toggle-", dir=workdir) as tmp:
        names = iter(Path(tmp) / f"rec{k}.mcap" for k in range(100))
        sink_class = recording_sink_class()

        def open_sink() -> Any:
            return sink_class(next(names), config, {"source": "toggle benchmark"})

        recorder = Recorder(open_sink, open_sink())
        runner = LiveRunner(source, config, [recorder, lat], description="toggle")
        runner.recording = recorder
        runner.start()
        player = start_virtual_board(sim, channel)
        try:
            t0 = time.time()
            time.sleep(before_s)
            out.before = _stats(lat.window(t0 + 1.0, time.time()))  # past the start-up
            for _ in range(toggles):
                sink = recorder.detach()  # r: stop (the App closes it on a worker thread)
                closer = threading.Thread(target=recorder.finish, args=(sink,))
                closer.start()
                time.sleep(0.5)
                started = time.time()
                recorder.start()  # r: start a new file
                ended = time.time()
                out.start_s.append(ended - started)
                delivered, gap = lat.deliveries(started, ended)
                out.during.append(delivered)
                out.gap_s.append(gap)
                closer.join(30.0)
                time.sleep(after_s)
                out.after.append(_stats(lat.window(started, time.time())))
        finally:
            player.stop()
            runner.stop(timeout=30.0)
            runner.wait(30.0)
        out.files = len(recorder.files)
        out.dropped = runner.frames_dropped
        if runner.error:
            out.errors.append(runner.error)
    return out


def measure(before_s: float = 3.0, after_s: float = 5.0, toggles: int = 2) -> list[Figure]:
    r = run(before_s, after_s, toggles)
    detail = (
        f"1 kHz x 3 ch, recording stopped and started {toggles}x; before: p99 "
        f"{r.before[1]:.2f} ms; starts took {', '.join(f'{s:.2f}' for s in r.start_s)} s"
    )
    return [
        Figure(
            "latency_p99_rec_toggle",
            f"latency p99, {after_s:g} s after r r",
            r.worst_after_p99,
            "ms",
            target=5.0,
            op="<=",
            detail=detail,
            error="; ".join(r.errors),
        )
    ]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--before", type=float, default=3.0, help="seconds before the first toggle")
    p.add_argument("--after", type=float, default=5.0, help="seconds measured after each start")
    p.add_argument("--toggles", type=int, default=2, help="how many stop+start pairs")
    args = p.parse_args(argv)
    result = run(args.before, args.after, args.toggles)
    print(result.report())
    return 0 if not result.errors else 1


if __name__ == "__main__":
    sys.exit(main())
