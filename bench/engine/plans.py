"""What the engine process builds: picklable plans, one per way of starting a live session.

A plan travels to the child process (pickled: plain values and module-level classes only)
and builds the session there with the same builders the commands always used
(:func:`bench.live.setup.open_live`, :func:`~bench.live.setup.open_emulator`,
:func:`~bench.live.setup.open_recording`, :func:`bench.live.session.live_session`), so there is
one way to build a live session whichever process it runs in.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.config import Config
from bench.live.setup import DEFAULT_LOG_DIR, LiveSetup


@dataclass(kw_only=True)
class EnginePlan:
    """Builds a session in the engine process; subclasses say which source and which log.

    ``started``, ``request`` and ``report`` are hooks for plans that do more than the
    commands (benchmarks, tests): start a board once the runner runs, answer their own
    requests, send figures back when the run is over."""

    config: Config
    log_dir: Path = DEFAULT_LOG_DIR
    record: bool = True
    lag_s: float | None = None  # `--lag`: the live model with this fixed lag (None: none)

    def open_setup(self) -> LiveSetup:
        raise NotImplementedError

    def open_first(self, setup: LiveSetup, warn: Callable[[str], None]) -> Any:
        """The first recording's sink (None: not recording at start)."""
        return None

    def build(self, warn: Callable[[str], None]) -> Any:
        """The session (not started); closes the source again if the recording fails."""
        from bench.live.session import live_session

        setup = self.open_setup()
        extra: list[Any] = []
        try:  # the extra sinks first: the recordings state the stream's address
            extra = self.open_extra_sinks(warn, setup.metadata)
            first = self.open_first(setup, warn)
        except BaseException:
            for sink in extra:
                sink.close()
            setup.close()
            raise
        session = live_session(
            setup, self.config, first, self.log_dir, record=self.record, lag_s=self.lag_s
        )
        assert session.runner is not None  # live_session always builds its runner
        for sink in extra:
            session.runner.add_sink(sink)
        return session

    def open_extra_sinks(
        self, warn: Callable[[str], None], metadata: dict[str, str] | None = None
    ) -> list[Any]:
        """Sinks beside the recording, e.g. the live Foxglove stream (``--foxglove``), whose
        address goes into ``metadata``."""
        from bench.mcaplog.foxglove_stream import open_stream

        stream = open_stream(getattr(self, "args", None), self.config, warn, metadata)
        return [stream] if stream is not None else []

    def started(self, session: Any) -> None:
        """Called once the runner runs."""

    def request(self, op: str, session: Any, *args: Any) -> Any:
        raise ValueError(f"unknown engine request {op!r}")

    def report(self, session: Any) -> dict[str, Any]:
        """Plan-specific figures, taken after the session has stopped."""
        return {}


def cli_values(args: argparse.Namespace) -> argparse.Namespace:
    """The parsed command line without the handler function: what a plan carries."""
    return argparse.Namespace(**{k: v for k, v in vars(args).items() if k != "func"})


@dataclass(kw_only=True)
class LivePlan(EnginePlan):
    """`bench tui` on a bus, a serial port or ``--emulate``: the parsed CLI values."""

    args: argparse.Namespace

    def open_setup(self) -> LiveSetup:
        from bench.live.setup import open_live

        return open_live(self.args)

    def open_first(self, setup: LiveSetup, warn: Callable[[str], None]) -> Any:
        from bench.live.setup import open_recording

        return open_recording(self.args, setup, self.config, warn=warn)


@dataclass(kw_only=True)
class EmulatorPlan(LivePlan):
    """`bench demo`: the virtual board playing ``scenario`` at ``speed``."""

    scenario: Path
    speed: float = 1.0

    def open_setup(self) -> LiveSetup:
        from bench.live.setup import open_emulator

        return open_emulator(self.scenario, speed=self.speed)


@dataclass(kw_only=True)
class BoardPlan(EnginePlan):
    """The virtual board playing a scenario dict, started once the runner runs (so no frame
    waits for the bench), for benchmarks and tests. ``sinks`` are extra sink factories
    built in the engine process and returned in the report (e.g. a latency histogram).

    Request ``drain``: stop the board, wait until every frame it sent went through the
    pipeline, and return the board's figures and how long that took."""

    scenario: dict[str, Any]
    speed: float = 1.0
    mcap: Path | None = None
    description: str = "virtual board (engine plan)"
    sinks: tuple[Callable[[], Any], ...] = ()
    _built: list[Any] = field(init=False, default_factory=list, repr=False)
    _sim: Any = field(init=False, default=None, repr=False)
    _channel: str = field(init=False, default="", repr=False)
    _t0: float = field(init=False, default=0.0, repr=False)

    def open_setup(self) -> LiveSetup:
        import os

        import can

        from devices.bus import CanBusSource

        self._channel = f"engine-board-{os.getpid()}-{id(self)}"
        bus = can.Bus(interface="virtual", channel=self._channel, receive_own_messages=False)
        source = CanBusSource(bus=bus, owns_bus=True, description=self.description)
        return LiveSetup(source, self.description, "engine-board")

    def open_first(self, setup: LiveSetup, warn: Callable[[str], None]) -> Any:
        from bench.live.setup import start_recording

        return start_recording(self.mcap, setup, self.config) if self.mcap is not None else None

    def build(self, warn: Callable[[str], None]) -> Any:
        from devices.emulator import scenario_from_dict, simulate

        self._sim = simulate(scenario_from_dict(self.scenario, "engine plan"))
        session = super().build(warn)
        self._built = [make() for make in self.sinks]
        for sink in self._built:
            session.runner.add_sink(sink)
        return session

    def started(self, session: Any) -> None:
        from devices.emulator import start_virtual_board

        board = start_virtual_board(self._sim, self._channel, speed=self.speed)
        session.setup.emulator = board
        self._t0 = time.perf_counter()

    def request(self, op: str, session: Any, *args: Any) -> Any:
        if op != "drain":
            return super().request(op, session, *args)
        return self._drain(session, float(args[0]) if args else 60.0)

    def _drain(self, session: Any, timeout: float) -> dict[str, Any]:
        board, runner = session.setup.emulator, session.runner
        board.stop()
        elapsed = time.perf_counter() - self._t0
        sent = int(board.frames_sent)
        stopped = time.monotonic()
        deadline = stopped + timeout
        while time.monotonic() < deadline and (
            runner.frames_received < sent or runner.pipeline.seq < sent
        ):
            time.sleep(0.005)  # the bus holds what was sent: let the bench take all of it
        drain_s = time.monotonic() - stopped
        snap = runner.snapshot(last=1)
        return {
            "sent": sent,
            "board_errors": int(board.errors),
            "elapsed": elapsed,
            "drain_s": drain_s,
            "snapshot_latency_ms": snap.latency_ms,
        }

    def report(self, session: Any) -> dict[str, Any]:
        return {"sinks": self._built}
