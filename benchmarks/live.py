"""The live pipeline on python-can's ``virtual`` bus: zero-loss frame rate and latency.

One run (:func:`run_live`) is what ``bench run --emulate`` / ``bench tui --emulate`` do:
the virtual board (:func:`devices.emulator.start_virtual_board`) plays a 1 kHz x 3 channel
scenario on a private virtual channel, ``speed`` times faster than real time for the rate
search; a :class:`devices.bus.CanBusSource` listens; a :class:`bench.live.runner.LiveRunner`
runs the pipeline; the live MCAP sink (:mod:`bench.mcaplog.writer_process`) logs; optionally the TUI
(:class:`bench.tui.app.BenchApp`) is attached, headless, polling snapshots as on a screen --
then, as in `bench tui`, board, source, runner, log and the latency histogram all run in the
engine process (:mod:`bench.engine.client`) and the App in this one.

* frames sent = the board's ``frames_sent`` (frames it handed to the bus without error);
  frames logged = frame messages in the finished MCAP file, counted by reading it back.
  A run is lossless when sent == received == logged, nothing was dropped anywhere and the
  file is complete. It *kept up* when, once the board stops, every frame is received and
  through the pipeline within ``KEEP_UP_S``: python-can's virtual bus queues without limit,
  so a bench that falls behind loses nothing there -- a real adapter's receive buffer would
  overflow instead. The zero-loss rate is the highest *achieved* rate of a run that was
  lossless and kept up; when the in-process board cannot send faster (it shares the GIL
  with the bench), that is said in the figure's note.
* latency = (wall time when the step's results reach the sinks) - (receive time of the
  sample's last frame, stamped by the virtual bus when the board sent it): the whole path
  acquisition -> queue -> decode/assemble/fuse -> sinks, for every result of the run.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import os
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.sinks.base import Sink
from benchmarks.common import Figure, board_frame_rate, board_scenario, live_cpu_text

RATE_TARGET = 20_000.0
P99_TARGET_MS = 5.0
PACE_TOLERANCE = 0.97
KEEP_UP_S = 0.5
MAX_BEHIND_S = 1.0
_ids = itertools.count(1)


class LatencySink(Sink):
    """Frame-to-result latency of every result, kept as a fixed log-spaced histogram (a Sink).

    Constant memory however long the run (0.1 % wide bins from 1 us to 1000 s), so a soak's
    memory figure measures the bench, not this instrument."""

    LO_MS = 1e-3
    HI_MS = 1e6
    BINS = 20_000

    def __init__(self) -> None:
        self._hist = np.zeros(self.BINS + 2, dtype=np.int64)  # [under, bins..., over]
        self._hist[:] = 0  # touch the pages now, not during the run
        self._scale = self.BINS / math.log(self.HI_MS / self.LO_MS)
        self.max_ms = float("nan")
        self.n = 0
        self.frames = 0
        self.results = 0
        self.at_end = 0

    def write(self, step: Any) -> None:
        now = time.time()
        self.frames += len(step.frames)
        res = step.results
        if len(res) == 0:
            return
        self.results += len(res)
        if step.batch is None:  # the end of the run emitted these (a sample cut short when
            self.at_end += len(res)  # the board stopped): no frame made them, no latency
            return
        hist, top = self._hist, self.BINS + 1
        for t in res["t"].tolist():  # a live step has a result or two: plain floats are cheapest
            lat = (now - t) * 1000.0
            if not math.isfinite(lat):
                continue
            pos = math.log(max(lat, self.LO_MS * 0.5) / self.LO_MS) * self._scale
            hist[min(max(math.floor(pos) + 1, 0), top)] += 1
            self.n += 1
            if not self.max_ms >= lat:
                self.max_ms = lat

    def percentile(self, q: float) -> float:
        """The q-th percentile (bin centre, 0.1 % resolution)."""
        if not self.n:
            return float("nan")
        k = int(np.searchsorted(np.cumsum(self._hist), q / 100.0 * self.n, side="left"))
        if k == 0:
            return self.LO_MS
        if k > self.BINS:
            return self.max_ms
        return float(self.LO_MS * np.exp((k - 0.5) / self._scale))


@dataclass
class LiveRun:
    rate_asked: float
    seconds: float
    tui: bool
    sent: int = 0
    received: int = 0
    dropped: int = 0
    logged: int = 0
    mcap_complete: bool = False
    mcap_dropped: int = 0
    board_errors: int = 0
    rate_achieved: float = 0.0
    drain_s: float = float("nan")
    results: int = 0
    p50_ms: float = float("nan")
    p99_ms: float = float("nan")
    max_ms: float = float("nan")
    snapshot_p99_ms: float = float("nan")
    tui_snapshots: int = 0
    stats: dict[str, Any] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    # a results CSV beside the MCAP (csv_opener): what the run said about it
    output_errors: list[str] = field(default_factory=list)
    csv_rows: int = 0
    csv_rows_lost: int = 0
    output_error_events: int = 0  # OUTPUT_ERROR events in the finished MCAP

    @property
    def lossless(self) -> bool:
        return (
            self.sent > 0
            and self.sent == self.received == self.logged
            and self.dropped == 0
            and self.mcap_dropped == 0
            and self.board_errors == 0
            and self.mcap_complete
            and not self.errors
        )

    @property
    def paced(self) -> bool:
        return self.rate_achieved >= PACE_TOLERANCE * self.rate_asked

    @property
    def drained(self) -> bool:
        return self.drain_s <= KEEP_UP_S

    @property
    def ok(self) -> bool:
        """The issue's criterion: sent = logged (nothing lost), and no backlog at the end."""
        return self.lossless and self.drained

    @property
    def strict(self) -> bool:
        """And the bench was never more than MAX_BEHIND_S behind during the run."""
        return self.ok and self.max_ms <= MAX_BEHIND_S * 1000.0

    def as_dict(self) -> dict[str, Any]:
        d = dict(self.__dict__)
        d["lossless"] = self.lossless
        d["paced"] = self.paced
        d["drained"] = self.drained
        d["strict"] = self.strict
        return d

    def summary(self) -> str:
        return (
            f"asked {self.rate_asked:,.0f}/s achieved {self.rate_achieved:,.0f}/s over "
            f"{self.seconds:.0f} s: sent {self.sent} received {self.received} logged "
            f"{self.logged} dropped {self.dropped}+{self.mcap_dropped}, drained in "
            f"{self.drain_s:.2f} s; latency p50 "
            f"{self.p50_ms:.2f} p99 {self.p99_ms:.2f} max {self.max_ms:.1f} ms"
            + (f"; errors: {'; '.join(self.errors)}" if self.errors else "")
        )


def _count_logged(path: Path) -> tuple[int, bool]:
    from bench.mcaplog.reader import McapLog
    from bench.mcaplog.schemas import FRAME_TOPIC

    with McapLog(path) as log:
        return int(log.message_counts().get(FRAME_TOPIC, 0)), bool(log.complete)


def _output_error_events(path: Path) -> int:
    from bench.mcaplog.recorded import read_events

    return sum(1 for e in read_events(path) if str(e.get("message", "")).startswith("OUTPUT_ERROR"))


def run_live(
    rate: float | None,
    seconds: float,
    *,
    tui: bool = False,
    workdir: str | None = None,
    faults: list[dict[str, Any]] | None = None,
    on_progress: Any = None,
    mcap_path: Path | None = None,
    csv_opener: Any = None,
    lag_s: float | None = None,
) -> LiveRun:
    """One live run; ``rate`` frames/s (None: the board's own 1 kHz pace, ~3.06 k frames/s);
    ``lag_s``: with the live model (`--lag`).

    ``csv_opener`` (without the TUI): also write the live results CSV, as `bench run --csv`
    does, through this stream opener (e.g. a file that fails mid-run)."""
    import can

    from bench.config import Config
    from bench.live.runner import LiveRunner
    from bench.live.setup import recording_sink_class
    from devices.bus import CanBusSource
    from devices.emulator import scenario_from_dict, simulate, start_virtual_board

    base = board_frame_rate()
    speed = 1.0 if rate is None else rate / base
    run = LiveRun(base * speed, seconds, tui)
    if tui:
        if csv_opener is not None:
            raise ValueError("a results CSV is for runs without the TUI")
        return _run_live_tui(run, speed, faults, on_progress, mcap_path, workdir, lag_s)
    scenario = scenario_from_dict(
        board_scenario(min(3600.0, seconds * speed + 2.0), faults=faults or []), "benchmark"
    )
    sim = simulate(scenario)
    config = Config(sample_rate_hz=scenario.sample_rate_hz)
    channel = f"bench-benchmark-{os.getpid()}-{next(_ids)}"
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    source = CanBusSource(bus=bus, owns_bus=True)
    lat = LatencySink()
    with tempfile.TemporaryDirectory(prefix="bench-live-", dir=workdir) as tmp:
        path = Path(mcap_path) if mcap_path is not None else Path(tmp) / "run.mcap"
        sink_class = recording_sink_class()  # what `bench run` logs with
        mcap = sink_class(path, config, {"source": "benchmark virtual board", "mode": "benchmark"})
        sinks: list[Any] = [mcap, lat]
        csv = None
        if csv_opener is not None:
            from bench.sinks.tables import csv_sink

            csv = csv_sink(Path(tmp) / "live.csv", live=True, opener=csv_opener)
            sinks.append(csv)
        runner = LiveRunner(source, config, sinks, description="benchmark", lag_s=lag_s)
        runner.recording = mcap
        runner.start()
        player = start_virtual_board(sim, channel, speed=speed)
        t0 = time.perf_counter()
        _wait(player, seconds, on_progress, runner)
        player.stop()
        elapsed = time.perf_counter() - t0
        run.sent = player.frames_sent
        run.board_errors = player.errors
        run.rate_achieved = run.sent / elapsed if elapsed > 0 else 0.0
        stopped = time.monotonic()
        deadline = stopped + 60.0
        while time.monotonic() < deadline and (
            runner.frames_received < run.sent or runner.pipeline.seq < run.sent
        ):
            time.sleep(0.005)  # the bus holds what was sent; let the bench take all of it
        run.drain_s = time.monotonic() - stopped
        snap = runner.snapshot(last=1)
        runner.stop(timeout=60.0)
        if not runner.wait(60.0):
            run.errors.append("runner did not finish within 60 s")
        run.received = runner.frames_received
        run.dropped = runner.frames_dropped
        run.mcap_dropped = mcap.dropped + mcap.frames_lost
        if runner.error:
            run.errors.append(runner.error)
        if mcap.error:
            run.errors.append(f"mcap: {mcap.error}")
        run.logged, run.mcap_complete = _count_logged(path)
        run.stats = runner.pipeline.stats.as_dict()
        run.output_errors = list(runner.output_errors)
        if csv is not None:
            run.csv_rows, run.csv_rows_lost = csv.rows, csv.rows_lost
            run.output_error_events = _output_error_events(path)
    run.results = lat.results
    run.p50_ms, run.p99_ms, run.max_ms = lat.percentile(50), lat.percentile(99), lat.max_ms
    run.snapshot_p99_ms = float(snap.latency_ms[1])
    return run


def _wait(player: Any, seconds: float, on_progress: Any, runner: Any) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end and not player.done:
        time.sleep(min(1.0, max(0.0, end - time.perf_counter())))
        if on_progress is not None:
            on_progress(runner)


def _run_live_tui(
    run: LiveRun,
    speed: float,
    faults: list[dict[str, Any]] | None,
    on_progress: Any,
    mcap_path: Path | None,
    workdir: str | None,
    lag_s: float | None = None,
) -> LiveRun:
    """The run as `bench tui --emulate` does it: board, source, runner, MCAP log and the
    LatencySink in the engine process (:mod:`bench.engine.client`), the App headless in this one.
    ``on_progress`` gets the session (it has ``snapshot`` and the engine's ``pid``)."""
    from bench.config import Config
    from bench.engine.client import start_engine
    from bench.engine.plans import BoardPlan

    scenario = board_scenario(min(3600.0, run.seconds * speed + 2.0), faults=faults or [])
    config = Config(sample_rate_hz=int(scenario.get("sample_rate_hz", 1000)))
    with tempfile.TemporaryDirectory(prefix="bench-live-", dir=workdir) as tmp:
        path = Path(mcap_path) if mcap_path is not None else Path(tmp) / "run.mcap"
        plan = BoardPlan(
            config=config,
            scenario=scenario,
            speed=speed,
            mcap=path,
            log_dir=Path(tmp),
            description="benchmark",
            sinks=(LatencySink,),
            lag_s=lag_s,
        )
        session = start_engine(plan)
        try:
            run.tui_snapshots, code = _with_tui(session, run.seconds, on_progress)
            if code:
                run.errors.append(f"the TUI exited with {code}")
            board = session.request("drain", 60.0)
        finally:
            session.stop(timeout=60.0)
        _take_engine_report(run, session, board)
        run.logged, run.mcap_complete = _count_logged(path)
    return run


def _take_engine_report(run: LiveRun, session: Any, board: dict[str, Any]) -> None:
    report = session.report
    if report is None:
        run.errors.append(session.runner.error or "the engine sent no report")
        return
    run.sent, run.board_errors = board["sent"], board["board_errors"]
    run.rate_achieved = run.sent / board["elapsed"] if board["elapsed"] > 0 else 0.0
    run.drain_s = board["drain_s"]
    run.snapshot_p99_ms = float(board["snapshot_latency_ms"][1])
    run.received, run.dropped = report.frames_received, report.frames_dropped
    status = report.last_status
    if status is not None:
        run.mcap_dropped = status.dropped + status.lost
        if status.error:
            run.errors.append(f"mcap: {status.error}")
    if report.error:
        run.errors.append(report.error)
    run.errors += [f"engine: {p}" for p in report.problems]
    run.stats = report.stats
    lat = report.plan["sinks"][0]
    run.results = lat.results
    run.p50_ms, run.p99_ms, run.max_ms = lat.percentile(50), lat.percentile(99), lat.max_ms


def _with_tui(session: Any, seconds: float, on_progress: Any) -> tuple[int, int]:
    """Run the bench TUI headless in this (main) thread for ``seconds`` on the engine's
    session, as `bench tui` would (it polls snapshots at its own rate, renders every
    panel); returns snapshots applied and the App's exit code."""
    from bench.tui.app import BenchApp

    app = BenchApp(session)

    def board_done() -> bool:
        snap = app.last_snapshot
        return snap is not None and bool(snap.extra.get("emulator_done"))

    async def pilot(p: Any) -> None:
        end = time.perf_counter() + seconds
        while time.perf_counter() < end and not board_done():
            await asyncio.sleep(min(1.0, max(0.0, end - time.perf_counter())))
            if on_progress is not None:
                on_progress(session)
        app.exit(0)

    code = app.run(headless=True, size=(160, 48), auto_pilot=pilot)
    return int(getattr(app, "snapshots_applied", 0)), int(code or app.return_code or 0)


# ------------------------------------------------------------------------------- figures
def _confirm(
    ladder: list[float], top: int, confirm_s: float, test: Any, runs: list[LiveRun], log: Any
) -> LiveRun | None:
    """Confirm ``ladder[top]`` over ``confirm_s`` (reusing a confirmation already run at that
    rate), stepping down the ladder until ``test`` holds."""
    for i in range(top, -1, -1):
        done = [
            r
            for r in runs
            if r.seconds == confirm_s and math.isclose(r.rate_asked, ladder[i], rel_tol=1e-9)
        ]
        r = done[0] if done else run_live(ladder[i], confirm_s)
        if not done:
            runs.append(r)
            log(f"  confirm {r.summary()}")
        if test(r):
            return r
    return None


def find_max_rate(
    probe_s: float, confirm_s: float, ladder: list[float], log: Any = print
) -> tuple[LiveRun | None, LiveRun | None, list[LiveRun]]:
    """Climb ``ladder`` with ``probe_s`` runs while they are lossless and drained (stopping
    early once the board cannot send faster), then confirm the best over ``confirm_s``,
    stepping down if the confirmation fails. Returns the confirmed runs for the issue's
    criterion (:attr:`LiveRun.ok`) and the strict one (:attr:`LiveRun.strict`)."""
    runs: list[LiveRun] = []
    top = strict_top = -1
    for i, rate in enumerate(ladder):
        r = run_live(rate, probe_s)
        runs.append(r)
        log(f"  probe   {r.summary()}")
        if not r.ok:
            break
        top = i
        if r.strict:
            strict_top = i
        if not r.paced:  # the sender is the limit: asking for more changes nothing
            break
    best = _confirm(ladder, top, confirm_s, lambda r: r.ok, runs, log)
    if best is not None and best.strict:
        return best, best, runs
    strict_top = min(
        strict_top, top - 1 if best is not None and best.rate_asked == ladder[top] else top
    )
    strict = _confirm(ladder, strict_top, confirm_s, lambda r: r.strict, runs, log)
    return best, strict, runs


def _rate_detail(r: LiveRun | None, confirm_s: float) -> str:
    if r is None:
        return "no rate on the ladder qualified"
    text = (
        f"sent = received = logged = {r.sent} over {confirm_s:.0f} s, MCAP complete, "
        f"drained {r.drain_s:.2f} s after the board stopped; at most {r.max_ms:.0f} ms behind "
        f"(p50 {r.p50_ms:.0f}, p99 {r.p99_ms:.0f} ms)"
    )
    if not r.paced:
        text += f"; the board was asked for {r.rate_asked:,.0f}/s (sender-limited)"
    return text


def measure_rate(confirm_s: float = 30.0, probe_s: float = 5.0, log: Any = print) -> list[Figure]:
    # 21 k: the target is 20 k *achieved*; an in-process board reaches ~99 % of what it is asked
    ladder = [5_000.0, 10_000.0, 15_000.0, 21_000.0, 25_000.0, 30_000.0, 40_000.0, 50_000.0]
    ladder += [70_000.0, 100_000.0, 140_000.0, 200_000.0]
    best, strict, runs = find_max_rate(probe_s, confirm_s, ladder, log)
    detail = _rate_detail(best, confirm_s)
    failed = [r for r in runs if r.seconds == probe_s and not r.ok]
    if failed:
        f = failed[0]
        why = "frames lost" if not f.lossless else f"{f.drain_s:.1f} s of backlog at the end"
        detail += f"; next step {f.rate_asked / 1e3:.0f} k: {why}"
    return [
        Figure(
            "live_max_rate",
            f"live zero-loss rate, virtual bus ({confirm_s:.0f} s)",
            best.rate_achieved if best is not None else 0.0,
            "frames/s",
            target=RATE_TARGET,
            detail=detail,
            extra={"runs": [r.as_dict() for r in runs], "ladder": ladder},
        ),
        Figure(
            "live_max_rate_strict",
            f"  ... and never > {MAX_BEHIND_S:g} s behind",
            strict.rate_achieved if strict is not None else 0.0,
            "frames/s",
            detail=_rate_detail(strict, confirm_s)
            + " (a real adapter's receive buffer holds far less than the virtual bus)",
        ),
    ]


def _cpu_ticks() -> tuple[int, int] | None:
    """(steal, total) jiffies of the whole machine (Linux), for the steal share of a run:
    time a virtual machine's CPUs were ready but the host ran something else."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            v = [int(x) for x in f.readline().split()[1:]]
        return v[7], sum(v)
    except (OSError, ValueError, IndexError):
        return None


def measure_latency(
    seconds: float = 30.0, tui: bool = False, lag_s: float | None = None
) -> list[Figure]:
    before = _cpu_ticks()
    r = run_live(None, seconds, tui=tui, lag_s=lag_s)
    after = _cpu_ticks()
    steal = ""
    if before is not None and after is not None and after[1] > before[1]:
        steal = f"; host steal {100.0 * (after[0] - before[0]) / (after[1] - before[1]):.1f} %"
    label = "TUI attached headless" if tui else "no TUI"
    if lag_s is not None:
        label += f", live model --lag {lag_s:g}"
    detail = (
        f"{r.results} results over {seconds:.0f} s at 1 kHz x 3 ch, MCAP on{steal}, "
        f"{live_cpu_text()}; "
        f"p50 {r.p50_ms:.2f} ms, max {r.max_ms:.1f} ms; lossless={r.lossless}, "
        f"drained {r.drain_s:.2f} s after the board stopped"
        + (f"; {r.tui_snapshots} TUI snapshots" if tui else "")
    )
    key = ("tui" if tui else "notui") + ("" if lag_s is None else "_lag")
    err = "; ".join(r.errors)
    return [
        Figure(
            f"latency_p50_{key}",
            f"latency p50, {label}",
            r.p50_ms,
            "ms",
            detail=f"1 kHz x 3 ch, {seconds:.0f} s",
            error=err,
        ),
        Figure(
            f"latency_p99_{key}",
            f"latency p99, {label}",
            r.p99_ms,
            "ms",
            target=P99_TARGET_MS,
            op="<=",
            detail=detail,
            error=err,
            extra=r.as_dict(),
        ),
    ]


if __name__ == "__main__":  # pragma: no cover - manual probing
    import sys

    rate = float(sys.argv[1]) if len(sys.argv) > 1 and sys.argv[1] != "board" else None
    secs = float(sys.argv[2]) if len(sys.argv) > 2 else 10.0
    lag = next((float(a[6:]) for a in sys.argv if a.startswith("--lag=")), None)
    print(run_live(rate, secs, tui="--tui" in sys.argv, lag_s=lag).summary())
    with contextlib.suppress(Exception):
        print(threading.enumerate())
