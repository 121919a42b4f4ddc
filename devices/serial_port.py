"""A live source on the board's UART (ICD section 2): 921600 8N1, COBS packets.

The port may be a USB adapter that vanishes when unplugged, so a failing read is a
"disconnect" notice and the source keeps trying to reopen the same path (a stable
``/dev/serial/by-id/...`` link survives re-enumeration) with backoff, reporting
"reconnect" when it is back. Nothing here raises into the pipeline after the first open.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

import serial

from devices.base import LiveSource, Reconnector, SourceBatch, SourceNotice
from devices.bus import one_line
from devices.errors import BenchError
from protocol.frames import empty_frames, frames_from_raw
from protocol.records import LinkError, RawFrame
from protocol.uart import Deframer

DEFAULT_BAUD = 921600
MAX_READ = 1 << 20
"""Bytes taken per read(): about 11 s of a saturated 921600 baud line, bounds a batch."""


def open_serial(port: str, baudrate: int = DEFAULT_BAUD, **kwargs: Any) -> serial.SerialBase:
    """Open ``port`` (a device path, pty or pyserial URL) at 8N1, non-blocking reads."""
    try:
        return serial.serial_for_url(
            port,
            baudrate=baudrate,
            bytesize=serial.EIGHTBITS,
            parity=serial.PARITY_NONE,
            stopbits=serial.STOPBITS_ONE,
            xonxoff=False,
            rtscts=False,
            timeout=0,
            **kwargs,
        )
    except Exception as exc:  # pyserial raises SerialException, ValueError, OSError...
        raise BenchError(
            f"cannot open serial port {port} at {baudrate} baud: {one_line(exc)}"
        ) from exc


class SerialSource(LiveSource):
    """Frames and link errors from the UART; ``t`` of a packet is the time of the read
    that completed it (the UART carries no timestamps)."""

    def __init__(
        self,
        port: str,
        baudrate: int = DEFAULT_BAUD,
        *,
        backoff_initial: float = 0.1,
        backoff_max: float = 5.0,
        **serial_kwargs: Any,
    ) -> None:
        self.port_name = port
        self.baudrate = int(baudrate)
        self.reconnector = Reconnector(backoff_initial, backoff_max)
        self._serial_kwargs = serial_kwargs
        self._closed = False
        self._timeout: float | None = 0.0
        self.deframer = Deframer()
        self.description = f"serial {port} @ {self.baudrate} baud"
        self._port: serial.SerialBase | None = open_serial(port, self.baudrate, **serial_kwargs)

    @property
    def connected(self) -> bool:
        return self._port is not None

    def _set_timeout(self, port: serial.SerialBase, timeout: float) -> None:
        # changing the timeout reconfigures the tty: only do it when it actually changes
        if timeout != self._timeout:
            port.timeout = timeout
            self._timeout = timeout

    def read(self, timeout: float) -> SourceBatch:
        if self._closed:
            return SourceBatch()
        port = self._port
        if port is None:
            return self._reconnect(timeout)
        timeout = max(0.0, timeout)
        notices: list[SourceNotice] = []
        chunk = b""
        try:
            self._set_timeout(port, timeout)
            chunk = port.read(1)
            if chunk:
                # already buffered: read() returns at once (every Serial class has
                # in_waiting; the stubs' SerialBase, which serial_for_url returns, has not)
                waiting: int = port.in_waiting  # type: ignore[attr-defined]  # see above
                if waiting:
                    chunk += port.read(min(waiting, MAX_READ))
        except Exception as exc:  # SerialException/OSError on unplug; none may escape
            detail = f"{self.description}: {one_line(exc)}"
            notices.append(SourceNotice(time.time(), "disconnect", detail))
        t = time.time()
        frames: list[RawFrame] = []
        errors: list[LinkError] = []
        if chunk:
            frames, errors = self.deframer.feed(chunk, t)
        if notices:
            # a packet cut by the disconnect never completes: report it, start clean
            _, lost = self.deframer.flush(t)
            errors.extend(lost)
            self._drop_port()
        return SourceBatch(frames_from_raw(frames) if frames else empty_frames(), errors, notices)

    def _drop_port(self) -> None:
        port, self._port = self._port, None
        self._timeout = None
        self.reconnector.dropped()
        if port is not None:
            with contextlib.suppress(Exception):  # already gone
                port.close()

    def _reconnect(self, timeout: float) -> SourceBatch:
        self._port = self.reconnector.attempt(
            timeout, lambda: open_serial(self.port_name, self.baudrate, **self._serial_kwargs)
        )
        if self._port is None:
            return SourceBatch()
        self._timeout = 0.0
        return SourceBatch(notices=[SourceNotice(time.time(), "reconnect", self.description)])

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        port, self._port = self._port, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
