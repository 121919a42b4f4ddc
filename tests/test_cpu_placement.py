"""Where the live path runs (devices/cpu_placement.py): the live threads -- acquisition,
processing, the in-process virtual board -- on one CPU, the MCAP writer process and the TUI's
screen on the others, as ``BENCH_LIVE_CPU`` says; a bad setting is one line, exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from bench.config import Config
from bench.errors import BenchError
from bench.live.runner import LiveRunner
from bench.sinks.base import Sink
from devices import cpu_placement
from devices.bus import CanBusSource
from devices.cpu_placement import (
    LIVE_CPU_ENV,
    live_cpu_label,
    live_cpus,
    other_cpus,
    pin_thread,
    restore_thread,
)
from tests.helpers import bench, until

ROOT = Path(__file__).resolve().parent.parent
placeable = pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="thread placement needs Linux and two CPUs",
)


def affinity(tid: int) -> set[int]:
    return set(os.sched_getaffinity(tid))


def placement() -> tuple[set[int], set[int], set[int]]:
    """(all CPUs this process may use, the live CPU ``auto`` picks, the others)."""
    allowed = set(os.sched_getaffinity(0))
    return allowed, {max(allowed)}, allowed - {max(allowed)}


def live_runner(channel: str, sinks: tuple[Sink, ...] = ()) -> LiveRunner:
    source = CanBusSource(bus=can.Bus(interface="virtual", channel=channel), owns_bus=True)
    return LiveRunner(source, Config(sample_rate_hz=200), list(sinks)).start()


@pytest.fixture
def two_cpus(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cpu_placement, "_allowed", frozenset({0, 1, 2, 5}))
    monkeypatch.delenv(LIVE_CPU_ENV, raising=False)


def test_auto_takes_the_highest_cpu_and_leaves_the_rest(two_cpus: None) -> None:
    assert live_cpus() == {5}
    assert other_cpus() == {0, 1, 2}
    assert live_cpu_label() == "5"


def test_a_chosen_cpu_and_off(two_cpus: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(LIVE_CPU_ENV, " 1 ")
    assert live_cpus() == {1} and other_cpus() == {0, 2, 5}
    monkeypatch.setenv(LIVE_CPU_ENV, "OFF")
    assert live_cpus() is None and other_cpus() is None
    assert live_cpu_label() == "any"


def test_one_cpu_places_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cpu_placement, "_allowed", frozenset({3}))
    monkeypatch.delenv(LIVE_CPU_ENV, raising=False)
    assert live_cpus() is None and other_cpus() is None
    monkeypatch.setenv(LIVE_CPU_ENV, "3")  # asked for: the live path gets it, nothing is left
    assert live_cpus() == {3} and other_cpus() is None


@pytest.mark.parametrize("value", ["7", "-1", "first", "1.0"])
def test_a_bad_setting_is_one_line_naming_it(
    two_cpus: None, monkeypatch: pytest.MonkeyPatch, value: str
) -> None:
    monkeypatch.setenv(LIVE_CPU_ENV, value)
    with pytest.raises(BenchError) as err:
        live_cpus()
    text = str(err.value)
    assert "\n" not in text and LIVE_CPU_ENV in text and "0, 1, 2, 5" in text


@placeable
def test_pin_and_restore_from_another_thread() -> None:
    allowed = set(os.sched_getaffinity(0))
    target = frozenset({max(allowed)})
    done = threading.Event()
    placed: list[object] = []

    def worker() -> None:
        placed.append(pin_thread(target))
        placed.append(set(os.sched_getaffinity(0)))
        done.wait(10)

    t = threading.Thread(target=worker)
    t.start()
    until(lambda: len(placed) == 2, "the worker to pin itself")
    assert placed[1] == set(target)
    restore_thread(placed[0])  # type: ignore[arg-type]
    assert affinity(t.native_id) == allowed
    done.set()
    t.join()
    assert pin_thread(None) is None


@placeable
def test_a_live_run_puts_its_threads_on_the_live_cpu(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from bench.mcaplog.writer_process import McapProcessSink
    from devices.emulator import scenario_from_dict, start_virtual_board

    monkeypatch.delenv(LIVE_CPU_ENV, raising=False)
    allowed, live, rest = placement()
    channel = f"placement-{os.getpid()}"
    sink = McapProcessSink(tmp_path / "placed.mcap", Config(sample_rate_hz=200))
    runner = live_runner(channel, (sink,))
    scenario = scenario_from_dict({"duration_s": 20, "sample_rate_hz": 200, "seed": 1}, "t")
    board = start_virtual_board(scenario, channel)
    try:
        until(lambda: runner.frames_received > 50, "frames")
        assert affinity(runner._acq.native_id) == live
        assert affinity(runner._proc.native_id) == live
        assert board.native_id is not None and affinity(board.native_id) == live
        assert affinity(sink._proc.pid) == rest  # the writer process: everything else
        assert affinity(threading.get_native_id()) == allowed  # the caller is left alone
    finally:
        board.stop()
        runner.stop()
        runner.wait(30)


@placeable
def test_off_leaves_the_live_threads_to_the_scheduler(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(LIVE_CPU_ENV, "off")
    allowed = set(os.sched_getaffinity(0))
    runner = live_runner(f"placement-off-{os.getpid()}")
    try:
        until(lambda: runner._proc.native_id is not None, "the threads")
        time.sleep(0.1)  # they pin themselves first thing, if at all
        assert affinity(runner._acq.native_id) == allowed
        assert affinity(runner._proc.native_id) == allowed
    finally:
        runner.stop()


@placeable
def test_the_screen_of_an_engine_stays_off_the_live_cpu(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from bench.engine.client import start_engine
    from bench.engine.plans import BoardPlan

    monkeypatch.delenv(LIVE_CPU_ENV, raising=False)
    allowed, _, rest = placement()
    plan = BoardPlan(
        config=Config(sample_rate_hz=200),
        scenario={"duration_s": 20, "sample_rate_hz": 200, "seed": 2},
        speed=1.0,
        mcap=tmp_path / "screen.mcap",
        log_dir=tmp_path,
    )
    session = start_engine(plan)
    try:
        assert set(os.sched_getaffinity(0)) == rest
        assert affinity(session._channel._reader.native_id) == rest
    finally:
        session.stop()
    assert set(os.sched_getaffinity(0)) == allowed  # given back when the engine is gone


def test_a_bad_setting_stops_the_cli_with_one_line(tmp_path: Path) -> None:
    env = dict(os.environ, **{LIVE_CPU_ENV: "not-a-cpu"})
    args = ["run", "--emulate", "devices/scenarios/demo.toml", "--duration", "1", "--no-log"]
    proc = bench(*args, env=env)
    assert proc.returncode == 2, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("bench: error:")]
    assert len(errors) == 1 and LIVE_CPU_ENV in errors[0], proc.stderr
    assert "Traceback" not in proc.stderr


@placeable
def test_a_board_in_a_process_of_its_own_keeps_off_the_live_cpu() -> None:
    """`bench emulate --pty` (or on a real bus) plays beside a bench, not inside one."""
    _, live, rest = placement()
    env = {k: v for k, v in os.environ.items() if k != LIVE_CPU_ENV}
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench", "emulate", "devices/scenarios/demo.toml", "--pty"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert "virtual board UART on" in proc.stdout.readline()
        tasks = Path(f"/proc/{proc.pid}/task")

        def masks() -> list[set[int]]:
            return [affinity(int(t.name)) for t in tasks.iterdir()]

        until(lambda: rest in masks(), "the player thread to place itself")
        assert live not in masks()
    finally:
        proc.terminate()
        proc.wait(30)
