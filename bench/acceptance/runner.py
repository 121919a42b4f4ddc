"""Acceptance runs: get the run's samples, measure every check, write the record.

Three ways to run a plan, one measuring path:

* emulated (default for a plan with a scenario): simulate the scenario, push its frames
  through the same Pipeline a live run uses as fast as possible (bench.replay.run.run_steps),
  with the MCAP sink writing DIR/run.mcap. Deterministic; no wall clock involved.
* realtime (``--realtime``): the same scenario played by the in-process virtual board on
  python-can's virtual bus, received by LiveRunner -- the live path end to end.
* live (source options): a real board (or ``--emulate SCENARIO``) through open_live and
  LiveRunner, with operator steps answered at the console, by ``--yes`` or a steps file.

Everything that can go wrong once the run has started becomes verdict "error" with the
reason in the record, so an unattended run always leaves junit.xml and record.json.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from bench import __version__
from bench.acceptance.answers import Answer, answer_for, parse_answer, schedule_steps, step_window
from bench.acceptance.checks.base import not_measured, wants_smoothing
from bench.acceptance.checks.registry import overall, run_check
from bench.acceptance.feeds import BATCH_FRAMES, can_batches, fault_infos, uart_batches
from bench.acceptance.model import Measurement, RunData, StepWindow
from bench.acceptance.outcome import RunOutcome
from bench.acceptance.plan import Plan, Step
from bench.acceptance.signoff import RunContext, board_identity
from bench.config import Config, load_config
from bench.errors import BenchError
from bench.pipeline.steps import Pipeline, StepOutput
from bench.records.events import EVENT_DTYPE, concat_events
from bench.records.results import RESULT_DTYPE
from bench.replay.run import run_steps
from bench.sinks.base import Sink
from devices.paths import write_file

SILENCE_S = 10.0
"""A live run with no new sample for this long (wall clock) has lost its board: error."""

DRAIN_S = 0.3
"""After the virtual board's last frame: time for it to cross the virtual bus."""


class Stopped(KeyboardInterrupt):
    """A signal (SIGTERM, SIGHUP) ended the run: handled like Ctrl-C, so the records are
    written, and said in them (``str()`` is the reason)."""


@dataclass
class StopRequest:
    """The reason a signal gave for ending the run, kept as well as raised.

    Python swallows an exception that a signal handler raises while a finaliser runs (a
    ``__del__`` the garbage collector calls: it prints "Exception ignored in" and goes on),
    and a run that missed its SIGTERM that way went on to its end. The run's loops therefore
    also :meth:`check` the request, and a run that finished regardless still ends in error."""

    reason: str | None = None

    def check(self) -> None:
        if self.reason is not None:
            raise Stopped(self.reason)


@dataclass
class Options:
    out_dir: Path
    realtime: bool = False
    speed: float = 1.0  # virtual board speed for --realtime
    yes: bool = False
    answers: list[Answer] | None = None
    config_path: str | None = None
    live_args: argparse.Namespace | None = None  # source options for a live run
    ask: Callable[[str], str] | None = None  # console input for operator steps
    say: Callable[[str], None] = lambda text: None
    plots: bool = True
    command: str = field(default_factory=lambda: " ".join(sys.argv))
    context: RunContext = field(default_factory=RunContext)  # unit, station, operator
    stop: StopRequest = field(default_factory=StopRequest)  # set by SIGTERM, SIGHUP


def has_live_source(args: argparse.Namespace | None) -> bool:
    if args is None:
        return False
    names = ("interface", "channel", "bitrate", "serial", "emulate")
    return any(getattr(args, n, None) is not None for n in names)


class Collector(Sink):
    """A sink that keeps every result and event of the run (thread-safe: a LiveRunner
    writes from its processing thread while the step engine reads the run time)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._results: list[np.ndarray] = []
        self._events: list[np.ndarray] = []
        self.last_n: int | None = None
        self.first_n: int | None = None
        self.updated = time.monotonic()

    def write(self, step: StepOutput) -> None:
        with self._lock:
            if len(step.results):
                self._results.append(step.results)
                if self.first_n is None:
                    self.first_n = int(step.results["n"][0])
                self.last_n = int(step.results["n"][-1])
                self.updated = time.monotonic()
            if len(step.events):
                self._events.append(step.events)

    def results(self) -> np.ndarray:
        with self._lock:
            parts = list(self._results)
        return np.concatenate(parts) if parts else np.zeros(0, dtype=RESULT_DTYPE)

    def events(self) -> np.ndarray:
        with self._lock:
            parts = list(self._events)
        return concat_events(parts) if parts else np.zeros(0, dtype=EVENT_DTYPE)


def count_logged_frames(path: Path) -> int:
    """Frames in an MCAP log, counted from the file itself (not from the writer)."""
    from bench.mcaplog import schemas
    from bench.mcaplog.reader import McapLog

    with McapLog(path) as log:
        return int(log.message_counts().get(schemas.FRAME_TOPIC, 0))


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def run_config(plan: Plan, config_path: str | None, emulate: str | None = None) -> Config:
    """--config wins (a real board's calibration sheet); else the emulated board as built
    (``--emulate SCENARIO``'s, or the plan's own) with the plan's [config] overlay; else the
    nominal values with the overlay."""
    if config_path:
        return load_config(config_path)
    if emulate:
        from bench.acceptance.plan import build_config
        from devices.emulator import load_scenario

        sc = load_scenario(emulate)
        name = Path(sc.path).name if sc.path else str(emulate)
        return build_config(sc, plan.config_overlay, plan.file, f"scenario {name}")
    return plan.config()


def _metadata(plan: Plan, config: Config, source: str, mode: str, command: str) -> dict[str, str]:
    meta = {
        "bench_version": __version__,
        "source": source,
        "config_source": config.source,
        "calibration": config.describe(),
        "config_toml": config.to_toml(),
        "command": command,
        "started_utc": _now(),
        "acceptance_plan": plan.name,
        "acceptance_mode": mode,
    }
    if plan.scenario is not None:
        meta["scenario"] = plan.scenario_ref or f"{plan.name} [scenario]"
    return meta


def _attachments(plan: Plan, config: Config) -> list[tuple[str, bytes]]:
    out = [(f"plan-{plan.name}.toml", plan.text.encode())]
    if plan.scenario is not None:
        out.append(("scenario.toml", plan.scenario_toml().encode()))
    out.append(("config.toml", config.to_toml().encode()))
    return out


def _rate(config: Config, pipeline: Pipeline | None, sim: Any) -> float:
    if sim is not None:
        return float(sim.scenario.sample_rate_hz)
    if pipeline is not None and pipeline.assembler.rate_known:
        return 1.0 / (pipeline.assembler.period_ticks * 1e-4)
    return float(config.sample_rate_hz)


def _run_data(
    collector: Collector,
    *,
    sim: Any,
    link: str,
    rate: float,
    mode: str,
    frames_sent: int | None,
    frames_received: int,
    frames_logged: int | None,
    frames_dropped: int = 0,
    steps: tuple[StepWindow, ...] = (),
    latency_ms: tuple[float, float] | None = None,
) -> RunData:
    results = collector.results()
    if sim is not None:
        n_ref = int(sim.scenario.counter0)
    else:
        n_ref = int(results["n"][0]) if len(results) else 0
    return RunData(
        results=results,
        events=collector.events(),
        rate_hz=rate,
        n_ref=n_ref,
        truth_gradient=None if sim is None else sim.truth["gradient_permil"].copy(),
        faults=() if sim is None else fault_infos(sim, link),
        frames_sent=frames_sent,
        frames_received=frames_received,
        frames_logged=frames_logged,
        frames_dropped=frames_dropped,
        steps=steps,
        latency_ms=latency_ms,
        mode=mode,
        link=link,
    )


def _board(config: Config, pipeline: Pipeline) -> dict[str, Any]:
    """The board as it identified itself (its base id and last BOARD_STATUS)."""
    return board_identity(config.base_id, pipeline.last_status, pipeline.stats.status_frames)


def _check_log(sink: Any) -> None:
    """A run whose MCAP log failed has no record to stand on: the bench failed."""
    if getattr(sink, "error", None):
        raise BenchError(f"the run's MCAP log failed: {sink.error}")


def _uart_sent(sim: Any) -> int:
    stream = sim.uart_stream()
    return len(stream) - stream.packets_broken


def _run_emulated(
    plan: Plan, config: Config, opts: Options, info: dict[str, Any]
) -> tuple[RunData, str]:
    """Simulate, then the pipeline as fast as it goes, logging to DIR/run.mcap."""
    from bench.mcaplog.sink import McapSink
    from devices.emulator import simulate

    sim = simulate(plan.scenario)
    info["simulation"] = sim.summary()
    source = f"emulated {plan.name} ({plan.link.upper()}, as fast as possible)"
    steps = schedule_steps(plan.steps, opts.answers)
    mcap_path = opts.out_dir / "run.mcap"
    sink = McapSink(
        mcap_path,
        config,
        _metadata(plan, config, source, "emulated", opts.command),
        _attachments(plan, config),
    )
    collector = Collector()
    pipeline = Pipeline(config)
    batches = uart_batches(sim) if plan.link == "uart" else can_batches(sim.frames)
    try:
        for step in run_steps(pipeline, batches):
            opts.stop.check()
            sink.write(step)
            collector.write(step)
    finally:
        sink.close()
    _check_log(sink)
    info["stats"] = pipeline.stats.as_dict()
    info["board"] = _board(config, pipeline)
    sent = _uart_sent(sim) if plan.link == "uart" else len(sim.frames)
    run = _run_data(
        collector,
        sim=sim,
        link=plan.link,
        rate=_rate(config, pipeline, sim),
        mode="emulated",
        frames_sent=sent,
        frames_received=pipeline.stats.frames,
        frames_logged=count_logged_frames(mcap_path),
        steps=steps,
    )
    return run, source


def _run_live(
    plan: Plan, config: Config, opts: Options, info: dict[str, Any], setup: Any, mode: str
) -> tuple[RunData, str]:
    """LiveRunner on an open source; operator steps in this thread; stop when done."""
    from bench.live.runner import LiveRunner
    from bench.live.setup import run_metadata
    from bench.mcaplog.sink import McapSink

    player = setup.emulator
    sim = getattr(player, "simulation", None)
    if sim is not None:
        info["simulation"] = sim.summary()
    meta = run_metadata(
        setup,
        config,
        {"acceptance_plan": plan.name, "acceptance_mode": mode, "command": opts.command},
    )
    collector = Collector()
    n_ref = int(sim.scenario.counter0) if sim is not None else None
    rate = float(sim.scenario.sample_rate_hz) if sim is not None else float(config.sample_rate_hz)

    def run_time() -> float | None:
        if collector.last_n is None:
            return None
        ref = n_ref if n_ref is not None else collector.first_n
        assert ref is not None  # first_n is set with last_n
        return (collector.last_n - ref) / rate

    def wait_until(t_s: float, what: str) -> None:
        while True:
            opts.stop.check()
            now = run_time()
            if now is not None and now >= t_s:
                return
            if player is not None and player.done and time.monotonic() - collector.updated > 1:
                raise BenchError(f"the virtual board finished before {what} ({t_s:g} s)")
            if time.monotonic() - collector.updated > SILENCE_S:
                raise BenchError(f"no sample from the board for {SILENCE_S:g} s ({what})")
            if runner.error:
                raise BenchError(runner.error)
            time.sleep(0.02)

    windows: list[StepWindow] = []
    unattended = opts.yes or opts.answers is not None
    prev_end = 0.0
    mcap_path = opts.out_dir / "run.mcap"
    sink = McapSink(mcap_path, config, meta, _attachments(plan, config))
    started = False
    try:  # from here a signal's Stopped stops the runner, the board and the log
        runner = LiveRunner(setup.source, config, [sink, collector], description=setup.description)
        runner.recording = sink
        runner.start()
        started = True
        setup.start_board()
        collector.updated = time.monotonic()
        for s in plan.steps:
            if s.at_s is not None:
                wait_until(s.at_s, f"step {s.index}")
            a = _ask(s, opts)
            if a.answer == "abort":
                raise BenchError(f"step {s.index} aborted by the operator")
            if unattended and s.at_s is not None:
                # a programmed table (or the rehearsal) is at the step from at_s on, as in
                # an emulated run; the time of the last processed sample would only add the
                # granularity of the batches the pipeline happened to get
                start = max(s.at_s, prev_end)
            else:
                start = run_time() or 0.0  # the operator's Enter
            w = step_window(s, a, start)
            prev_end = w.to_s if a.answer != "skip" else start
            windows.append(w)
            runner.mark(f"step {s.index} {a.answer}: {s.prompt} (expect {w.expected_permil:g})")
            if a.answer != "skip":
                opts.say(f"step {s.index}: settling {s.settle_s:g} s, measuring {s.measure_s:g} s")
                wait_until(w.to_s, f"the end of step {s.index}")
        if not plan.steps and plan.duration_s is not None:
            wait_until(plan.duration_s, "the plan's duration_s")
        if player is not None and (not plan.steps or mode == "realtime"):
            while not player.done:
                opts.stop.check()
                if runner.error:
                    raise BenchError(runner.error)
                time.sleep(0.05)
    finally:
        if player is not None:
            if not player.done:
                player.stop()
            time.sleep(DRAIN_S)  # frames still crossing the virtual bus are the run's too
        if started:
            runner.stop()
        else:
            sink.close()  # the runner closes its sinks; one that never ran does not
        setup.close()
    if runner.error:
        raise BenchError(runner.error)
    _check_log(sink)
    info["stats"] = runner.pipeline.stats.as_dict()
    info["board"] = _board(config, runner.pipeline)
    sent = getattr(player, "frames_sent", None) if player is not None else None
    snap = runner.snapshot(last=1)
    run = _run_data(
        collector,
        sim=sim,
        link="uart" if getattr(opts.live_args, "serial", None) else "can",
        rate=_rate(config, runner.pipeline, sim),
        mode=mode,
        frames_sent=sent,
        frames_received=runner.pipeline.stats.frames,
        frames_logged=count_logged_frames(mcap_path),
        frames_dropped=runner.frames_dropped,
        steps=tuple(windows),
        latency_ms=snap.latency_ms,
    )
    return run, setup.description


def _ask(step: Step, opts: Options) -> Answer:
    if opts.answers is not None:
        a = answer_for(step, opts.answers)
        opts.say(f"step {step.index}: {step.prompt} -> {a.answer} (steps file)")
        return a
    if opts.yes:
        opts.say(f"step {step.index}: {step.prompt} -> ok (--yes)")
        return Answer()
    ask = opts.ask or input
    text = (
        f"\nstep {step.index}: {step.prompt}\n"
        f"  expected {step.gradient_permil:g} permil. Enter = go on, a number = the reference "
        "reading in permil, s = skip, q = abort: "
    )
    try:
        return parse_answer(ask(text))
    except EOFError:
        return Answer("abort")


def prepare_out_dir(path: Path) -> Path:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BenchError(f"cannot create output folder {path}: {exc.strerror or exc}") from None
    return path


def run_plan(plan: Plan, opts: Options) -> RunOutcome:
    """Run a plan and measure its checks; write junit.xml, record.json, report.html.

    Operator mistakes found before the run starts (no source, bad config, no way to answer
    the steps) raise BenchError; anything after that is verdict "error" in the record."""
    from bench.live.setup import open_emulator, open_live

    out = prepare_out_dir(opts.out_dir)
    config = run_config(plan, opts.config_path, getattr(opts.live_args, "emulate", None))
    opts.say(config.announcement())
    live = has_live_source(opts.live_args)
    if live:
        mode = "live"
    elif plan.emulated:
        mode = "realtime" if opts.realtime else "emulated"
    else:
        raise BenchError(
            f"plan {plan.name!r} has no scenario: it runs against a board "
            "(give --interface/--channel, --serial PORT or --emulate SCENARIO)"
        )
    if mode == "realtime" and plan.link == "uart":
        raise BenchError(
            f"plan {plan.name!r} listens on the UART: --realtime plays the virtual board on "
            "CAN only (run it without --realtime, or on a serial port)"
        )
    if (
        mode != "emulated"
        and plan.steps
        and not opts.yes
        and opts.answers is None
        and opts.ask is None
        and not sys.stdin.isatty()
    ):
        raise BenchError(
            "the plan has operator steps and nobody to answer them: "
            "use --yes or --steps FILE for an unattended run"
        )
    scenario_path = out / "scenario.toml"
    if plan.scenario is not None and mode != "live":
        # the emulated board as a file: `bench emulate DIR/scenario.toml` replays it
        write_file(scenario_path, plan.scenario_toml())
    setup = None
    if mode == "live":
        assert opts.live_args is not None  # a live mode is chosen from them
        setup = open_live(opts.live_args)
    elif mode == "realtime":
        setup = open_emulator(scenario_path, speed=opts.speed)
    started = _now()
    t0 = time.monotonic()
    info: dict[str, Any] = {}
    run: RunData | None = None
    error: str | None = None
    source = setup.description if setup is not None else f"emulated {plan.name}"
    try:
        if setup is None:
            run, source = _run_emulated(plan, config, opts, info)
        else:
            run, source = _run_live(plan, config, opts, info, setup, mode)
        if wants_smoothing(plan.checks):
            from bench.acceptance.smoothing import smoothed_run

            run = smoothed_run(run, out / "run.mcap", config, info)
        measurements = [run_check(c, run) for c in plan.checks]
        opts.stop.check()  # a signal whose raise a finaliser swallowed
    except KeyboardInterrupt as exc:
        error = str(exc) if isinstance(exc, Stopped) else "interrupted by the operator"
    except BenchError as exc:
        error = str(exc)
    except Exception as exc:  # the bench failed: say so in the record, exit 2
        error = f"the bench failed: {exc!r}"
    if error is not None:
        measurements = [not_measured(c, "error", f"not measured: {error}") for c in plan.checks]
    verdict = "error" if error is not None else overall(measurements)
    outcome = RunOutcome(
        plan=plan,
        verdict=verdict,
        measurements=measurements,
        run=run,
        config=config,
        mode=mode,
        source=source,
        started_utc=started,
        finished_utc=_now(),
        wall_s=time.monotonic() - t0,
        out_dir=out,
        error=error,
        info=info,
        context=opts.context.with_board(info.get("board")),
    )
    from bench.acceptance.report.write import write_reports

    write_reports(outcome, plots=opts.plots)
    return outcome


def remeasure(outcome: RunOutcome, mcap_path: Path | None = None) -> list[Measurement]:
    """The checks again, from the run's MCAP log replayed through a fresh pipeline.

    What the log cannot hold (emulator truth, fault record, frames sent, step windows) is
    taken from the original run; samples, events and frame counts come from the file."""
    from devices.formats import open_log

    assert outcome.run is not None
    path = mcap_path or outcome.files["mcap"]
    source = open_log(path)
    collector = Collector()
    pipeline = Pipeline(outcome.config)
    try:
        for step in run_steps(pipeline, source.batches(BATCH_FRAMES)):
            collector.write(step)
    finally:
        source.close()
    old = outcome.run
    run = RunData(
        results=collector.results(),
        events=collector.events(),
        rate_hz=old.rate_hz,
        n_ref=old.n_ref,
        truth_gradient=old.truth_gradient,
        faults=old.faults,
        frames_sent=old.frames_sent,
        frames_received=pipeline.stats.frames,
        frames_logged=count_logged_frames(path),
        frames_dropped=old.frames_dropped,
        steps=old.steps,
        latency_ms=old.latency_ms,
        mode=old.mode,
        link=old.link,
    )
    if wants_smoothing(outcome.plan.checks):
        from bench.acceptance.smoothing import smoothed_run

        run = smoothed_run(run, Path(path), outcome.config)
    return [run_check(c, run) for c in outcome.plan.checks]
