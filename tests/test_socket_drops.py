"""The kernel's socket drop count, from the source to the record: overflow notices, the
SOCKET_OVERFLOW event, Stats, /bench/health, the MCAP's notices, the TUI's bus line.

The socket itself (SO_RXQ_OVFL on a real kernel) is tested in tests/vcan/; here fake buses
stand in for it, with counts chosen by hand.
"""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from bench.config import Config
from bench.mcaplog.reader import McapLog
from bench.mcaplog.sink import McapSink
from bench.pipeline.steps import Pipeline
from bench.records.events import EventKind, describe
from bench.sinks.base import Sink
from bench.tui.panels.board import board_lines
from devices import bus as bus_module
from devices.base import LiveSource, SourceBatch, SourceNotice
from devices.bus import CanBusSource
from tests.helpers import instant, pack


class FakeSocketBus(can.BusABC):
    """Hands out queued messages; ``kernel_drops`` and ``rcvbuf_bytes`` as set by the test;
    ``fail_once`` raises (like ENETDOWN) before the messages still queued."""

    def __init__(self, granted: int = 16 << 20, requested: int = 8 << 20) -> None:
        super().__init__(channel="fake")
        self.queue: list[can.Message] = []
        self.kernel_drops = 0
        self.rcvbuf_bytes = granted
        self.rcvbuf_requested = requested
        self.fail_once = False

    def put(self, n: int) -> None:
        self.queue += [can.Message(arbitration_id=0x555, data=bytes(8)) for _ in range(n)]

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.fail_once:
            self.fail_once = False
            raise can.CanOperationError("Error receiving: Network is down", 100)
        return (self.queue.pop(0) if self.queue else None), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        raise NotImplementedError


@pytest.fixture
def buses(monkeypatch: pytest.MonkeyPatch) -> list[FakeSocketBus]:
    """Every bus CanBusSource opens, in order (the first as opened, each reopen after)."""
    made: list[FakeSocketBus] = []

    def open_bus(config: dict) -> FakeSocketBus:
        made.append(FakeSocketBus(granted=4608, requested=1 << 20) if made else FakeSocketBus())
        return made[-1]

    monkeypatch.setattr(bus_module, "open_bus", open_bus)
    monkeypatch.setattr(bus_module, "resolve_bus_config", lambda *a, **k: {"interface": "x"})
    return made


def test_overflow_notices_carry_what_the_kernel_dropped_across_a_reconnect(buses) -> None:
    src = CanBusSource("socketcan", "vcan0", backoff_initial=0.0)
    first = buses[0]
    first.put(2)
    batch = src.read(0)
    assert len(batch.frames) == 2
    assert [
        (n.kind, n.detail.endswith("socket receive buffer 16777216 bytes")) for n in batch.notices
    ] == [("info", True)]
    first.kernel_drops = 3  # the next frames were queued after 3 were dropped
    first.put(1)
    batch = src.read(0)
    assert [(n.kind, n.count) for n in batch.notices] == [("overflow", 3)]
    assert batch.notices[0].t == batch.frames["t"][-1]  # stamped by the frame that told
    assert "dropped 3 frames" in batch.notices[0].detail and "3 in all" in batch.notices[0].detail
    assert not src.read(0).notices  # unchanged count: nothing more to say
    # the link goes down with 2 frames still queued: they come with the disconnect
    first.put(2)
    first.fail_once = True
    batch = src.read(0)
    assert len(batch.frames) == 2
    assert [n.kind for n in batch.notices] == ["disconnect"]
    assert [n.kind for n in src.read(0).notices] == ["reconnect"]
    second = buses[1]  # a new socket counts from 0; granted less than asked
    second.put(1)
    batch = src.read(0)
    assert [n.kind for n in batch.notices] == ["info"]
    assert "4608 bytes (asked for 1048576: capped by net.core.rmem_max)" in batch.notices[0].detail
    second.kernel_drops = 2
    second.put(1)
    assert [(n.kind, n.count) for n in src.read(0).notices] == [("overflow", 2)]
    assert src.kernel_drops == 5
    src.close()


def _steps_with_overflows() -> list[SourceBatch]:
    frames = [pack(instant(k, t0=100.0)) for k in range(4)]
    return [
        SourceBatch(frames[0]),
        SourceBatch(frames[1], notices=[SourceNotice(100.006, "overflow", "lost 7", 7)]),
        SourceBatch(frames[2], notices=[SourceNotice(100.011, "info", "buffer", 0)]),
        SourceBatch(frames[3], notices=[SourceNotice(100.016, "overflow", "lost 5", 5)]),
    ]


def test_an_overflow_notice_is_an_event_counted_in_the_run_stats() -> None:
    pipe = Pipeline(Config())
    events = np.concatenate([pipe.process(b).events for b in _steps_with_overflows()])
    ours = events[events["kind"] == EventKind.SOCKET_OVERFLOW]
    assert ours["value"].tolist() == [7, 5]
    assert ours["t"].tolist() == [100.006, 100.016]
    assert pipe.stats.socket_drops == 12
    assert pipe.stats.as_dict()["socket_drops"] == 12
    assert describe(ours[0]) == (
        "SOCKET_OVERFLOW 7 frames dropped by the kernel (socket receive buffer full)"
    )
    # a replay-sized step counts them with numpy: the same total
    big = Pipeline(Config())
    notices = [SourceNotice(100.0 + k, "overflow", "", k + 1) for k in range(40)]
    big.process(SourceBatch(np.concatenate([pack(instant(k)) for k in range(40)]), [], notices))
    assert big.stats.socket_drops == sum(range(1, 41))


def test_the_mcap_keeps_the_count_and_health_reports_the_total(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    sink = McapSink(path, Config(), {"source": "socket drops"}, health_interval_s=0.001)
    pipe = Pipeline(Config())
    for batch in _steps_with_overflows():
        sink.write(pipe.process(batch))
    sink.write(pipe.finish())
    sink.close()
    with McapLog(path) as log:
        notices = log.read_frames()[2]
        health = log.json_topic("/bench/health")
    assert [(n.kind, n.count) for n in notices] == [("overflow", 7), ("info", 0), ("overflow", 5)]
    assert health[-1]["socket_drops"] == 12
    replayed = Pipeline(Config())
    for batch in McapLog(path).iter_batches():
        replayed.process(batch[0] if isinstance(batch, tuple) else batch)
    assert replayed.stats.socket_drops == 12  # the replay of the log counts them again


def test_the_tui_bus_line_shows_the_kernel_drops() -> None:
    from bench.live.runner import LiveRunner

    pipe = Pipeline(Config())
    for batch in _steps_with_overflows():
        pipe.process(batch)

    class _Source:
        description = "fake"

        def read(self, timeout: float) -> SourceBatch:
            return SourceBatch()

        def close(self) -> None:
            pass

    runner = LiveRunner(_Source(), Config())  # type: ignore[arg-type]
    runner.pipeline = pipe
    bus = [line for line in board_lines(runner.snapshot()).plain.splitlines() if "bus" in line]
    assert bus and "kdrop 12" in bus[0]


def test_stop_waits_for_the_sinks_to_close_even_past_the_acquisition_timeout() -> None:
    """A slow close (a backlog, the MCAP summary on a loaded machine) must finish before
    stop() returns: the process would otherwise end with an unfinished log."""
    import time

    from bench.live.runner import LiveRunner

    class _Idle(LiveSource):
        description = "idle"

        def read(self, timeout: float) -> SourceBatch:
            time.sleep(timeout)
            return SourceBatch()

        def close(self) -> None:
            pass

    class _SlowSink(Sink):
        closed = False

        def write(self, step: object) -> None:
            pass

        def close(self) -> None:
            time.sleep(1.0)
            self.closed = True

    sink = _SlowSink()
    runner = LiveRunner(_Idle(), Config(), [sink])
    runner.start()
    runner.stop(timeout=0.1)
    assert sink.closed and runner.error is None
    late = _SlowSink()
    runner = LiveRunner(_Idle(), Config(), [late])
    runner.start()
    runner.stop(timeout=0.1, close_timeout=0.2)
    assert not late.closed and "may be unfinished" in str(runner.error)
