"""``python -m benchmarks.replay_seek [LOG] [--at 327] [--repeat 3]``: how long the replay TUI's
``b`` takes, and whether its progress moves.

``b`` starts the replay again and seeks the log time 10 s before the sample shown; this
does the same on the replay TUI's own session (``bench.live.session``: ReplaySource,
LiveRunner, ReplayTap), without a screen: a fresh paused session on the log, a seek to
``--at`` seconds of log time, timed until it pauses there. Without LOG it writes the demo
scenario's 9-minute emulator log (``bench emulate devices/scenarios/demo.toml --out``) into
a temporary folder first. Prints wall and CPU time (of this process: the runner's threads)
of each seek and the progress figures seen meanwhile. Quote the load average with it.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def seek_once(path: Path, at_s: float, log_dir: Path) -> tuple[float, float, list[float]]:
    """(wall s, CPU s, progress figures) of one seek to ``at_s`` s of log time."""
    from bench.config_choice import replay_config
    from bench.live.session import live_session, replay_setup

    config = replay_config(None, path)
    session = live_session(replay_setup(path, config, paused=True), config, None, log_dir)
    session.start()
    try:
        replay = session.replay
        assert replay is not None
        while not math.isfinite(replay.status().log_t0):
            time.sleep(0.01)
        t0 = replay.status().log_t0
        wall, cpu = time.perf_counter(), time.process_time()
        replay.seek_time(t0 + at_s)
        seen: list[float] = []
        while replay.seeking:
            time.sleep(0.05)
            seen.append(replay.status().fraction)
        return time.perf_counter() - wall, time.process_time() - cpu, seen
    finally:
        session.stop()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("log", nargs="?", help="a log to seek in (default: the demo's, written now)")
    p.add_argument("--at", type=float, default=327.0, help="log time to seek to, s (5:27)")
    p.add_argument("--repeat", type=int, default=3)
    a = p.parse_args(argv)
    from bench.pipeline.warmup import prepare

    prepare(lambda m: print(f"bench: {m}", file=sys.stderr))
    with tempfile.TemporaryDirectory(prefix="bench-seek-") as tmp:
        path = Path(a.log) if a.log else Path(tmp) / "demo.mcap"
        if not a.log:
            from bench.cli import main as bench

            demo = ROOT / "devices" / "scenarios" / "demo.toml"
            if bench(["emulate", str(demo), "--out", str(path)]) != 0:
                return 1
        print(f"load average {os.getloadavg()[0]:.2f} (1 min) on {os.cpu_count()} CPUs")
        for _ in range(a.repeat):
            wall, cpu, seen = seek_once(path, a.at, Path(tmp))
            steps = ", ".join(f"{100 * f:.0f}%" for f in seen[:: max(1, len(seen) // 8)])
            print(f"seek to {a.at:g} s: {wall:.2f} s wall, {cpu:.2f} s CPU; progress {steps}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
