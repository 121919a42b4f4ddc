"""The TUI on a 1 kHz board: frames sent = frames received = frames logged.

``python -m benchmarks.tui_1khz [--seconds 60]`` runs the whole `bench tui --emulate` stack
headless (App.run_test, 100x30, 4 Hz snapshots, every panel rendered): in the engine process
(bench/engine/) the virtual board plays a 1 kHz x 3 channel scenario (~3060 frames/s with
BOARD_STATUS and SPEED_REF) on a private python-can virtual channel, a CanBusSource listens,
the session runs the LiveRunner and records through its Recorder into an MCAP file; in this
process the App polls it, operator marks are pressed on the way, and ``q`` quits exactly as
an operator would (which finishes the MCAP file).

It then prints frames sent (the board's own count), received (the runner's), processed (the
pipeline's), logged (frames read back from the finished MCAP file), the drop counters and the
display rate, and exits 1 unless sent = received = processed = logged with nothing dropped.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


@dataclass
class TuiRun:
    seconds: float
    sent: int = 0
    received: int = 0
    processed: int = 0
    logged: int = 0
    runner_dropped: int = 0
    log_dropped: int = 0
    board_errors: int = 0
    mcap_complete: bool = False
    marks_logged: int = 0
    snapshots: int = 0
    elapsed: float = 0.0
    errors: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return (
            self.sent > 0
            and self.sent == self.received == self.processed == self.logged
            and self.runner_dropped == 0
            and self.log_dropped == 0
            and self.board_errors == 0
            and self.mcap_complete
            and not self.errors
        )

    def report(self) -> str:
        rate = self.sent / self.elapsed if self.elapsed else 0.0
        lines = [
            f"TUI on a 1 kHz x 3 ch virtual board, {self.seconds:g} s ({rate:,.0f} frames/s), "
            "MCAP on, 100x30 headless",
            f"  frames sent      {self.sent}",
            f"  frames received  {self.received}",
            f"  frames processed {self.processed}",
            f"  frames logged    {self.logged}  (read back from the finished MCAP file)",
            f"  dropped          runner queue {self.runner_dropped}, log {self.log_dropped}, "
            f"board send errors {self.board_errors}",
            f"  MCAP complete    {self.mcap_complete}; operator marks in it: {self.marks_logged}",
            f"  display          {self.snapshots} snapshots shown "
            f"({self.snapshots / self.elapsed if self.elapsed else 0:.1f} Hz)",
        ]
        lines += [f"  error: {e}" for e in self.errors]
        lines.append("  PASS: sent = received = logged" if self.ok else "  FAIL")
        return "\n".join(lines)


def run(
    seconds: float = 60.0, workdir: str | None = None, marks: int = 3, lag_s: float | None = None
) -> TuiRun:
    """One run; ``lag_s``: with the live model (`--lag`), its panel and lagged line drawn."""
    from bench.config import Config
    from bench.engine.client import start_engine
    from bench.engine.plans import BoardPlan
    from bench.tui.app import BenchApp
    from benchmarks.common import board_scenario

    out = TuiRun(seconds)
    scenario = board_scenario(seconds + 1.0)
    config = Config(sample_rate_hz=int(scenario.get("sample_rate_hz", 1000)))
    with tempfile.TemporaryDirectory(prefix="bench-tui-", dir=workdir) as tmp:
        path = Path(tmp) / "tui.mcap"
        plan = BoardPlan(
            config=config,
            scenario=scenario,
            mcap=path,
            log_dir=Path(tmp),
            description="virtual board 1 kHz",
            lag_s=lag_s,
        )
        session = start_engine(plan)
        try:
            asyncio.run(_drive(BenchApp(session, poll_hz=4.0), session, out, marks))
        finally:
            session.stop()
        _collect(out, session, path)
    return out


async def _drive(app: Any, session: Any, out: TuiRun, marks: int) -> None:
    """The operator's part: watch, press m now and then, and q once the board is done."""
    async with app.run_test(size=(100, 30)) as pilot:
        t0 = time.perf_counter()
        end = t0 + out.seconds
        mark_at = [t0 + out.seconds * (i + 1) / (marks + 1) for i in range(marks)]
        while time.perf_counter() < end and not _board_done(app):
            await asyncio.sleep(0.2)
            if mark_at and time.perf_counter() >= mark_at[0]:
                mark_at.pop(0)
                await pilot.press("m")
        board = await asyncio.to_thread(session.request, "drain", 30.0)
        out.elapsed = board["elapsed"]
        out.sent, out.board_errors = board["sent"], board["board_errors"]
        out.snapshots = app.snapshots_applied
        await pilot.press("q")  # the operator's quit: stops the run, finishes the MCAP
        deadline = time.monotonic() + 60.0
        while app.is_running and time.monotonic() < deadline:
            await asyncio.sleep(0.05)
        if app.is_running:
            out.errors.append("the TUI did not quit within 60 s")


def _board_done(app: Any) -> bool:
    snap = app.last_snapshot
    return snap is not None and bool(snap.extra.get("emulator_done"))


def _collect(out: TuiRun, session: Any, path: Path) -> None:
    """The engine's figures, and the finished MCAP file read back."""
    from bench.mcaplog.reader import McapLog
    from bench.mcaplog.recorded import read_events

    report = session.report
    if report is None:
        out.errors.append(session.runner.error or "the engine sent no report")
        return
    out.received, out.processed = report.frames_received, report.frames_processed
    out.runner_dropped = report.frames_dropped
    status = report.last_status
    if status is not None:
        out.log_dropped = status.dropped + status.lost
    if report.error:
        out.errors.append(report.error)
    if status is not None and status.error:
        out.errors.append(f"mcap: {status.error}")
    out.errors += [f"engine: {p}" for p in report.problems]
    with McapLog(path) as log:
        frames, _, _ = log.read_frames()
        out.logged = len(frames)
        out.mcap_complete = bool(log.complete)
    out.marks_logged = sum(
        1 for e in read_events(path) if "operator mark" in str(e.get("message", e))
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=60.0, help="run length (default 60)")
    p.add_argument("--lag", type=float, metavar="S", help="with the live model, lag S seconds")
    args = p.parse_args(argv)
    result = run(args.seconds, lag_s=args.lag)
    print(result.report())
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
