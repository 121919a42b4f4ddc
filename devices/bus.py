"""A live CAN source over any python-can bus (socketcan, vcan, pcan, kvaser, slcan, virtual...).

Every adapter goes through the same code: only the constructor call to ``can.Bus`` differs,
and it is resolved exactly like ``python -m can.logger`` does, so an operator's
``~/.canrc`` / ``can.ini`` / ``CAN_INTERFACE`` settings work unchanged. Bus trouble never
raises into the pipeline: it becomes a "disconnect" notice and, for a bus this source
opened itself, a reopen with backoff and a "reconnect" notice.
"""

from __future__ import annotations

import contextlib
import errno
import math
import time
from collections.abc import Sequence
from typing import Any

import can
import numpy as np

from devices.base import LiveSource, Reconnector, SourceBatch, SourceNotice
from devices.errors import BenchError
from protocol.frames import FRAME_DTYPE
from protocol.records import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE

NO_SOCKETCAN = (
    "this kernel has no SocketCAN (Errno 97, EAFNOSUPPORT: containers and many cloud VMs "
    "have none); try the bench on vcan in a VM: tools/vcan-vm (README, 'Trying SocketCAN')"
)
"""What an operator reads when the kernel cannot make a CAN socket at all."""

BURST_LIMIT = 4096
"""Frames drained into one batch after the first: bounds latency and memory of a batch."""


def one_line(exc: BaseException) -> str:
    """An exception as one line for an operator message (python-can messages can be multi-line)."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 300 else text[:297] + "..."


def frames_from_messages(msgs: Sequence[can.Message]) -> np.ndarray:
    """python-can Messages -> FRAME_DTYPE array (data cut/padded to 8, dlc kept as received)."""
    n = len(msgs)
    out = np.zeros(n, dtype=FRAME_DTYPE)
    if not n:
        return out
    out["t"] = [m.timestamp for m in msgs]
    out["id"] = [m.arbitration_id & 0xFFFFFFFF for m in msgs]
    out["dlc"] = [min(m.dlc, 255) for m in msgs]
    out["flags"] = [
        (FLAG_EXTENDED if m.is_extended_id else 0)
        | (FLAG_REMOTE if m.is_remote_frame else 0)
        | (FLAG_ERROR if m.is_error_frame else 0)
        | (FLAG_FD if m.is_fd else 0)
        for m in msgs
    ]
    padded = b"".join(bytes(m.data[:8]).ljust(8, b"\0") for m in msgs)
    out["data"] = np.frombuffer(padded, dtype=np.uint8).reshape(n, 8)
    return out


def messages_from_frames(frames: np.ndarray, channel: Any = None) -> list[can.Message]:
    """FRAME_DTYPE array -> python-can Messages (payload is data[:min(dlc, 8)], none if remote).

    The inverse of :func:`frames_from_messages` for classic frames; used to feed python-can
    writers and to put emulated frames on a bus.
    """
    rows = zip(
        frames["t"].tolist(),
        frames["id"].tolist(),
        frames["dlc"].tolist(),
        frames["flags"].tolist(),
        frames["data"].tolist(),
        strict=True,
    )
    out = []
    for t, can_id, dlc, flags, data in rows:
        remote = bool(flags & FLAG_REMOTE)
        out.append(
            can.Message(
                timestamp=t,
                arbitration_id=can_id,
                is_extended_id=bool(flags & FLAG_EXTENDED),
                is_remote_frame=remote,
                is_error_frame=bool(flags & FLAG_ERROR),
                is_fd=bool(flags & FLAG_FD),
                dlc=dlc,
                data=None if remote else bytes(data[: min(dlc, 8)]),
                channel=channel,
            )
        )
    return out


def resolve_bus_config(
    interface: str | None = None,
    channel: Any = None,
    bitrate: int | None = None,
    config_context: str | None = None,
    **kwargs: Any,
) -> dict[str, Any]:
    """The full bus config python-can would use: given values win, the rest comes from
    can.rc, CAN_* environment variables and the config files (can.util.load_config).

    Mirrors ``python -m can.logger`` (can.cli.create_bus_from_namespace): only values that
    were actually given are passed, plus ``single_handle=True``.
    """
    given: dict[str, Any] = {"single_handle": True, **kwargs}
    for key, value in (("interface", interface), ("channel", channel), ("bitrate", bitrate)):
        if value is not None:
            given[key] = value
    try:
        config = dict(can.util.load_config(config=given, context=config_context))
    except can.CanInterfaceNotImplementedError as exc:
        if given.get("interface") is None:
            raise BenchError(
                "cannot open can bus: no interface given and none configured "
                "(use --interface, bench.toml, ~/.canrc or CAN_INTERFACE)"
            ) from exc
        raise BenchError(f"cannot open can bus: {one_line(exc)}") from exc
    except (ValueError, TypeError) as exc:
        raise BenchError(f"cannot open can bus: bad python-can config: {one_line(exc)}") from exc
    return config


def describe_config(config: dict[str, Any]) -> str:
    text = f"interface={config.get('interface')} channel={config.get('channel')}"
    if config.get("bitrate"):
        text += f" bitrate={config['bitrate']}"
    return text


def open_bus(config: dict[str, Any]) -> can.BusABC:
    """Build the bus from a resolved config; any failure is one BenchError line.

    socketcan gets :class:`devices.socketcan_rx.SocketcanRxBus` (python-can's bus with a
    large receive buffer and the kernel's drop count; ``rcvbuf`` in the config sizes it);
    every other interface is python-can's own.
    """
    try:
        if config.get("interface") == "socketcan":
            from devices.socketcan_rx import SocketcanRxBus

            kwargs = {k: v for k, v in config.items() if k != "interface"}
            return SocketcanRxBus(**kwargs)
        return can.Bus(ignore_config=True, **config)
    except Exception as exc:  # backends raise anything from CanError to ImportError/OSError
        why = one_line(exc)
        if isinstance(exc, OSError) and exc.errno == errno.EAFNOSUPPORT:
            why = NO_SOCKETCAN
        raise BenchError(f"cannot open can bus {describe_config(config)}: {why}") from exc


class CanBusSource(LiveSource):
    """Frames from a python-can bus, batched per :meth:`read` call.

    Either give interface/channel/bitrate (+ backend kwargs; missing values come from
    python-can's config) and the source opens, owns and reopens the bus, or give an already
    built ``bus`` (e.g. the emulator's ``virtual`` bus), which is never reopened and is shut
    down on close only when ``owns_bus`` is true. ``description`` names the source in
    notices and the UI (default: the bus settings).
    """

    def __init__(
        self,
        interface: str | None = None,
        channel: Any = None,
        bitrate: int | None = None,
        *,
        bus: can.BusABC | None = None,
        owns_bus: bool = False,
        description: str | None = None,
        config_context: str | None = None,
        burst_limit: int = BURST_LIMIT,
        backoff_initial: float = 0.1,
        backoff_max: float = 5.0,
        **kwargs: Any,
    ) -> None:
        self.burst_limit = max(1, int(burst_limit))
        self.reconnector = Reconnector(backoff_initial, backoff_max)
        self._closed = False
        self.kernel_drops = 0
        """Frames the kernel dropped at the socket (socketcan), over every reconnect."""
        self._bus_drops = 0  # the current bus's count when it was last reported
        self._opened = True  # a bus (re)opened whose receive buffer is not reported yet
        self._config: dict[str, Any] | None
        if bus is not None:
            if interface is not None or channel is not None or bitrate is not None or kwargs:
                raise BenchError("cannot open can bus: give either a bus or its settings, not both")
            self._config = None
            self._owns_bus = owns_bus
            self._bus: can.BusABC | None = bus
            self.description = f"can bus {getattr(bus, 'channel_info', type(bus).__name__)}"
        else:
            self._config = resolve_bus_config(
                interface, channel, bitrate, config_context=config_context, **kwargs
            )
            self._owns_bus = True
            self._bus = open_bus(self._config)
            self.description = f"can bus {describe_config(self._config)}"
        if description is not None:
            self.description = description

    @classmethod
    def from_bus(cls, bus: can.BusABC, *, owns_bus: bool = False, **kwargs: Any) -> CanBusSource:
        return cls(bus=bus, owns_bus=owns_bus, **kwargs)

    @property
    def bus(self) -> can.BusABC | None:
        """The current bus (None while disconnected)."""
        return self._bus

    @property
    def connected(self) -> bool:
        return self._bus is not None

    def read(self, timeout: float) -> SourceBatch:
        if self._closed:
            return SourceBatch()
        bus = self._bus
        if bus is None:
            return self._reconnect(timeout)
        msgs: list[can.Message] = []
        notices = self._buffer_notice(bus) if self._opened else []
        self._opened = False
        failure: Exception | None = None
        try:
            msg = bus.recv(max(0.0, timeout))
            if msg is not None:
                msgs.append(msg)
                while len(msgs) < self.burst_limit:
                    msg = bus.recv(0)
                    if msg is None:
                        break
                    msgs.append(msg)
        except Exception as exc:  # CanError, OSError, ...: backends differ, none may escape
            failure = exc
            self._drain(bus, msgs)
        notices += self._overflow_notice(bus, msgs)
        if failure is not None:
            detail = f"{self.description}: {one_line(failure)}"
            notices.append(SourceNotice(time.time(), "disconnect", detail))
            self._drop_bus()
        return SourceBatch(frames_from_messages(msgs), [], notices)

    def _drain(self, bus: can.BusABC, msgs: list[can.Message]) -> None:
        """Take the frames a failing bus still holds. A socket reports an error before the
        frames queued ahead of it (socketcan: ENETDOWN when the link goes down), and
        closing it would lose them; reading on after the error returns them."""
        with contextlib.suppress(Exception):  # a bus that fails again has nothing left
            while len(msgs) < self.burst_limit:
                msg = bus.recv(0)
                if msg is None:
                    break
                msgs.append(msg)

    def _buffer_notice(self, bus: can.BusABC) -> list[SourceNotice]:
        """An "info" notice with the socket receive buffer the kernel granted (socketcan)."""
        granted = getattr(bus, "rcvbuf_bytes", None)
        if granted is None:
            return []
        asked = int(getattr(bus, "rcvbuf_requested", 0))
        detail = f"{self.description}: socket receive buffer {granted} bytes"
        if granted < 2 * asked:  # the kernel doubles what it grants
            detail += f" (asked for {asked}: capped by net.core.rmem_max)"
        return [SourceNotice(time.time(), "info", detail)]

    def _overflow_notice(self, bus: can.BusABC, msgs: list[can.Message]) -> list[SourceNotice]:
        """An "overflow" notice when the kernel's drop count of this socket went up."""
        drops = int(getattr(bus, "kernel_drops", 0))
        if drops == self._bus_drops:
            return []
        lost, self._bus_drops = drops - self._bus_drops, drops
        self.kernel_drops += lost
        t = msgs[-1].timestamp if msgs else time.time()  # the frame that brought the count
        detail = (
            f"{self.description}: the kernel dropped {lost} frames at the socket "
            f"(receive buffer full; {self.kernel_drops} in all)"
        )
        return [SourceNotice(t, "overflow", detail, lost)]

    def _drop_bus(self) -> None:
        bus, self._bus = self._bus, None
        self._bus_drops = 0  # the next socket counts from 0
        self.reconnector.dropped()
        if bus is not None and self._owns_bus:
            # the adapter is already gone; a failing shutdown has nothing left to report
            with contextlib.suppress(Exception):
                bus.shutdown()

    def _reconnect(self, timeout: float) -> SourceBatch:
        """Sleep until the next attempt is due (at most ``timeout``), then try to reopen."""
        config = self._config
        if config is None:  # a bus we were handed cannot be rebuilt here
            time.sleep(max(0.0, timeout))
            return SourceBatch()
        opened_at = [math.nan]

        def reopen() -> can.BusABC:
            opened_at[0] = time.time()
            return open_bus(config)

        self._bus = self.reconnector.attempt(timeout, reopen)
        if self._bus is None:
            return SourceBatch()
        self._opened = True
        # stamped when the new socket was opened: every frame it receives comes after it
        notice = SourceNotice(opened_at[0], "reconnect", self.description)
        return SourceBatch(notices=[notice])

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        bus, self._bus = self._bus, None
        if bus is not None and self._owns_bus:
            bus.shutdown()
