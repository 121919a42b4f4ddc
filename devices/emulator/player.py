"""Players: put a simulation on a python-can bus or a pseudo-terminal in real time, or into a
file as fast as possible. This is the emulator's imperative shell; the model stays pure.

Real-time players are threads that send each frame (or UART packet) at
``start + (t - t0) / speed``; when they fall behind (a GC pause, a slow bus) they send what is
due at once rather than drifting late for the rest of the run.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import select
import struct
import termios
import threading
import time
import tty
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from devices.cpu_placement import live_cpus, pin_thread
from devices.emulator.scenario import Scenario, load_scenario
from devices.emulator.simulation import Simulation, UartStream, simulate
from devices.emulator.two_boards import BusRun, simulate_bus
from devices.errors import BenchError

if TYPE_CHECKING:
    import can  # imported where used: starting a replay need not load python-can


class _PacedPlayer(threading.Thread):
    """Emits items i..j whose relative times have come; subclasses define :meth:`_emit`."""

    def __init__(
        self, times_s: np.ndarray, speed: float, name: str, cpus: frozenset[int] | None = None
    ) -> None:
        super().__init__(name=name, daemon=True)
        self.cpus = cpus  # where the thread runs (None: wherever the scheduler puts it)
        if not speed > 0:
            raise BenchError(f"--speed must be > 0, got {speed!r}")
        self._times = np.ascontiguousarray(times_s, dtype=np.float64)
        self.speed = float(speed)
        self._halt = threading.Event()
        self._started_at: float | None = None
        self._next = 0
        self.error: BaseException | None = None

    def _emit(self, i: int, j: int) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        pass

    def run(self) -> None:
        pin_thread(self.cpus)
        times, n = self._times, len(self._times)
        self._started_at = time.perf_counter()
        try:
            while self._next < n and not self._halt.is_set():
                now = (time.perf_counter() - self._started_at) * self.speed
                i = self._next
                if times[i] > now:  # the usual case at real-time pace: nothing due yet
                    j = i
                elif i + 1 == n or times[i + 1] > now:  # exactly one due (no numpy call)
                    j = i + 1
                else:
                    j = int(np.searchsorted(times, now, side="right"))
                if j > i:
                    j = min(j, self._next + 4096)  # stay responsive to stop()
                    self._emit(self._next, j)
                    self._next = j
                else:
                    self._halt.wait(min((times[self._next] - now) / self.speed, 0.05))
        except BaseException as exc:  # reported to the caller, never lost in the thread
            self.error = exc
        finally:
            self._close()

    @property
    def progress_s(self) -> float:
        """How far into the run (scenario seconds) the player is."""
        if self._started_at is None:
            return 0.0
        if not self.is_alive():
            return float(self._times[self._next - 1]) if self._next else 0.0
        return (time.perf_counter() - self._started_at) * self.speed

    @property
    def done(self) -> bool:
        """True once the thread has finished (everything sent, stopped, or failed)."""
        return self._started_at is not None and not self.is_alive()

    @property
    def items_total(self) -> int:
        return len(self._times)

    def begin(self) -> None:
        """Start playing unless already started (a player may be built before its listener
        is ready and started once it is)."""
        if self.ident is None and not self._halt.is_set():
            self.start()

    def wait(self, timeout: float | None = None) -> bool:
        """Block until done (or timeout); True when done."""
        self.join(timeout)
        return not self.is_alive()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop sending and release the bus or pty. Safe to call twice or before start."""
        self._halt.set()
        if self.is_alive():
            self.join(timeout)
        elif self._started_at is None:
            self._close()


class CanPlayer(_PacedPlayer):
    """Plays ``sim.frames`` on a python-can bus in real time.

    Send errors (bus off, buffer full) are counted in ``errors`` and play goes on; a frame
    that failed is not retried, as a real board would not retry it either.
    """

    def __init__(
        self,
        sim: Simulation | BusRun,
        bus: can.BusABC,
        *,
        speed: float = 1.0,
        own_bus: bool = True,
        cpus: frozenset[int] | None = None,
    ) -> None:
        super().__init__(sim.frames["t"] - sim.t0, speed, name="virtual-board-can", cpus=cpus)
        self.simulation = sim
        self.bus = bus
        self._own_bus = own_bus
        self.frames_sent = 0
        self.errors = 0
        self.last_error = ""

    def _emit(self, i: int, j: int) -> None:
        import can

        f = self.simulation.frames
        ids = f["id"][i:j].tolist()
        payload = f["data"][i:j].tobytes()
        send = self.bus.send
        for k, can_id in enumerate(ids):
            msg = can.Message(
                arbitration_id=can_id, data=payload[8 * k : 8 * k + 8], is_extended_id=False
            )
            try:
                send(msg, timeout=0.05)
                self.frames_sent += 1
            except (can.CanError, OSError) as exc:
                self.errors += 1
                self.last_error = str(exc)
                if self._halt.wait(0.001):
                    return

    def _close(self) -> None:
        if self._own_bus:
            with contextlib.suppress(Exception):
                self.bus.shutdown()


class PtyPlayer(_PacedPlayer):
    """Writes the UART byte stream to a pseudo-terminal in real time.

    A reader opens ``slave_path`` like a serial port. The slave is put in raw mode so the
    tty layer neither echoes nor rewrites bytes. When nobody reads and the pty buffer is
    full, the stale bytes are flushed and counted in ``bytes_discarded``: like a real UART,
    the board never waits for a listener.
    """

    def __init__(
        self,
        stream: UartStream,
        t0: float,
        *,
        speed: float = 1.0,
        cpus: frozenset[int] | None = None,
    ) -> None:
        super().__init__(stream.packet_t - t0, speed, name="virtual-board-pty", cpus=cpus)
        self.stream = stream
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self.master, False)
        self.slave_path = os.ttyname(self._slave)
        self.packets_written = 0
        self.bytes_written = 0
        self.bytes_discarded = 0
        self._closed = False

    @property
    def frames_sent(self) -> int:
        return self.packets_written

    def _emit(self, i: int, j: int) -> None:
        ends = self.stream.packet_end
        lo = int(ends[i - 1]) if i else 0
        chunk = memoryview(self.stream.data)[lo : int(ends[j - 1])]
        while len(chunk) and not self._halt.is_set():
            try:
                n = os.write(self.master, chunk)
                self.bytes_written += n
                chunk = chunk[n:]
            except BlockingIOError:
                _, writable, _ = select.select([], [self.master], [], 0.2)
                if not writable:  # nobody is reading: drop the stale bytes, keep going
                    pending = self._pending()
                    termios.tcflush(self._slave, termios.TCIFLUSH)
                    self.bytes_discarded += pending
            except OSError as exc:
                if exc.errno != errno.EIO:
                    raise
                return
        self.packets_written += j - i

    def _pending(self) -> int:
        """Bytes written but not yet read by whoever has the slave open."""
        raw = fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0")
        return int(struct.unpack("i", raw)[0])

    def _close(self) -> None:
        if self._closed:
            return
        # Closing the master hangs the line up and loses what the reader has not taken
        # yet, so give it a second to read the tail of the stream.
        deadline = time.monotonic() + 1.0
        drained = 0
        while not self._halt.is_set() and time.monotonic() < deadline and drained < 2:
            time.sleep(0.02)
            try:
                drained = drained + 1 if self._pending() == 0 else 0
            except OSError:
                break
        self._closed = True
        for fd in (self.master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)


def _open_virtual(channel: str) -> can.BusABC:
    import can

    try:
        return can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    except (can.CanError, OSError, ValueError) as exc:
        raise BenchError(f"cannot open virtual CAN channel {channel!r}: {exc}") from None


def _as_simulation(scenario: Scenario | Simulation | BusRun | str | Path) -> Simulation | BusRun:
    if isinstance(scenario, Simulation | BusRun):
        return scenario
    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    return simulate_bus(scenario) if scenario.second_board else simulate(scenario)


def start_virtual_board(
    scenario: Scenario | Simulation | BusRun | str | Path,
    channel_name: str,
    *,
    speed: float = 1.0,
    start: bool = True,
) -> CanPlayer:
    """Start the virtual board on python-can's in-process ``virtual`` interface.

    The receiver opens its own ``can.Bus(interface="virtual", channel=channel_name)`` --
    before calling this, or it misses the first frames. Returns the running player (with
    ``start=False`` a ready one: ``begin()`` starts it): it has ``frames_sent``, ``errors``,
    ``done``, ``progress_s``, ``simulation`` and ``stop()``. A scenario with
    ``[second_board]`` plays both boards on the one bus (devices.emulator.two_boards).
    """
    sim = _as_simulation(scenario)
    # python-can's virtual bus is in-process: this board shares the GIL with the bench that
    # listens, so it runs on the live path's CPU (devices.cpu_placement)
    bus = _open_virtual(channel_name)
    player = CanPlayer(sim, bus, speed=speed, own_bus=True, cpus=live_cpus())
    if start:
        player.start()
    return player


# ----------------------------------------------------------------------------- file output


def write_truth_csv(path: str | Path, truth: np.ndarray) -> None:
    """The truth as CSV, one row per sampling instant (columns: engine.TRUTH_COLUMNS),
    whole or not at all (a temporary name renamed into place)."""
    from devices.emulator.stream_out import write_truth_rows
    from devices.paths import staged

    p = Path(path)
    try:
        with staged(p) as tmp, tmp.open("wb") as f:
            write_truth_rows(f, truth, header=True)
    except OSError as exc:
        raise BenchError(f"{p}: cannot write: {exc.strerror or exc}") from None
