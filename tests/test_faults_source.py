"""The source goes away and comes back: the bench says so, keeps the log valid, and resumes.

* The bench's own CAN adapter disappears (its python-can ``virtual`` bus is shut down under
  it) and is reopened by :class:`devices.bus.CanBusSource`.
* The board goes away and comes back on the bus (its virtual bus closed, a new board
  started on the same channel with its counters restarted).
* The UART adapter is unplugged: the pseudo-terminal behind a stable ``/dev/serial/by-id``
  style link is closed, a new one appears behind the same link.

Each run has the live runner and the MCAP sink; the log must be complete and hold every
frame the runner received, with the disconnect and reconnect recorded.
"""

from __future__ import annotations

import itertools
import os
import time
from pathlib import Path
from typing import Any

import can

from bench.config import Config
from bench.live.runner import LiveRunner
from bench.records.events import EventKind
from devices.emulator import PtyPlayer, scenario_from_dict, simulate, start_virtual_board
from tests.helpers import until

_ids = itertools.count(1)
CONFIG = Config(sample_rate_hz=200)


def sim(seconds: float = 20.0, seed: int = 1) -> Any:
    return simulate(
        scenario_from_dict({"duration_s": seconds, "sample_rate_hz": 200, "seed": seed})
    )


def event_kinds(runner: LiveRunner) -> list[int]:
    return [kind for _, kind, _ in runner.snapshot(last=1).events]


def start(source: Any, tmp_path: Path) -> tuple[LiveRunner, Any, Path]:
    from bench.mcaplog.sink import McapSink

    path = tmp_path / "run.mcap"
    mcap = McapSink(path, CONFIG, {"source": "fault test"}, flush_interval_s=0.2)
    runner = LiveRunner(source, CONFIG, [mcap], description="fault test", read_timeout=0.02)
    runner.recording = mcap
    return runner.start(), mcap, path


def finish(runner: LiveRunner, mcap: Any, path: Path) -> dict[str, int]:
    """Stop, then check the log: complete, every received frame in it, the notices kept."""
    from bench.mcaplog.reader import McapLog
    from bench.mcaplog.schemas import FRAME_TOPIC, NOTICE_TOPIC

    runner.stop()
    assert runner.wait(10.0)
    assert runner.error is None, runner.error
    assert mcap.error is None, mcap.error
    with McapLog(path) as log:
        assert log.complete, log.truncation
        counts = log.message_counts()
        notices = [n["kind"] for n in log.json_topic(NOTICE_TOPIC)]
    assert counts[FRAME_TOPIC] == runner.frames_received
    assert runner.frames_dropped == 0
    return {k: notices.count(k) for k in ("disconnect", "reconnect")}


def test_adapter_lost_and_reopened_on_the_virtual_bus(tmp_path: Path) -> None:
    from devices.bus import CanBusSource

    channel = f"fault-adapter-{os.getpid()}-{next(_ids)}"
    source = CanBusSource(
        interface="virtual", channel=channel, receive_own_messages=False, backoff_initial=0.05
    )
    runner, mcap, path = start(source, tmp_path)
    board = start_virtual_board(sim(), channel)
    try:
        until(lambda: runner.frames_received > 300, what="frames before the fault")
        source.bus.shutdown()  # the adapter is gone: the next read fails
        until(lambda: EventKind.RECONNECT in event_kinds(runner), what="a reconnect event")
        after = runner.frames_received
        until(lambda: runner.frames_received > after + 300, what="frames after reconnect")
    finally:
        board.stop()
    kinds = event_kinds(runner)
    assert kinds.index(EventKind.DISCONNECT) < kinds.index(EventKind.RECONNECT)
    notices = finish(runner, mcap, path)
    assert notices == {"disconnect": 1, "reconnect": 1}


def test_board_leaves_the_bus_and_comes_back(tmp_path: Path) -> None:
    from devices.bus import CanBusSource

    channel = f"fault-board-{os.getpid()}-{next(_ids)}"
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    runner, mcap, path = start(CanBusSource(bus=bus, owns_bus=True), tmp_path)
    first = start_virtual_board(sim(seed=1), channel)
    second = None
    try:
        until(lambda: runner.frames_received > 300, what="frames from the first board")
        first.stop()  # power cut: its bus is shut down
        time.sleep(0.3)
        sent_before = first.frames_sent
        second = start_virtual_board(sim(seed=2), channel)  # counters start again
        until(lambda: second.frames_sent > 300, what="frames from the second board")
        second.stop()
        total = sent_before + second.frames_sent
        until(lambda: runner.frames_received >= total, what="every frame sent")
    finally:
        first.stop()
        if second is not None:
            second.stop()
    finish(runner, mcap, path)
    assert runner.frames_received == total
    assert runner.pipeline.stats.samples > 0


def test_uart_unplugged_and_replugged_behind_a_stable_link(tmp_path: Path) -> None:
    from devices.serial_port import SerialSource

    s = sim()
    stream = s.uart_stream()
    link = tmp_path / "usb-ACB3-if00"  # what /dev/serial/by-id gives a USB adapter
    first = PtyPlayer(stream, s.t0)
    os.symlink(first.slave_path, link)
    first.start()
    source = SerialSource(str(link), backoff_initial=0.05)
    runner, mcap, path = start(source, tmp_path)
    second = None
    try:
        until(lambda: runner.frames_received > 200, what="UART frames before unplug")
        first.stop()  # the pty is closed: reads fail with EIO
        until(lambda: EventKind.DISCONNECT in event_kinds(runner), what="a disconnect event")
        second = PtyPlayer(stream, s.t0)
        link.unlink()
        os.symlink(second.slave_path, link)
        second.start()
        until(lambda: EventKind.RECONNECT in event_kinds(runner), what="a reconnect event")
        after = runner.frames_received
        until(lambda: runner.frames_received > after + 200, what="frames after replug")
    finally:
        first.stop()
        if second is not None:
            second.stop()
    notices = finish(runner, mcap, path)
    assert notices["disconnect"] >= 1 and notices["reconnect"] >= 1
