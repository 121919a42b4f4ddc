"""SocketCAN reception that cannot lose frames silently: a large receive buffer and the
kernel's own count of the frames it dropped at the socket.

A raw CAN socket holds received frames in its receive buffer until they are read; when a
slow reader lets it fill, the kernel drops the newest frames and counts them (``sk_drops``).
python-can's ``SocketcanBus`` neither sizes that buffer nor reads that count: it asks
``recvmsg`` for room for exactly one control message (the ``SO_TIMESTAMPNS`` receive time)
and asserts that it got only that one. :class:`SocketcanRxBus` is python-can's bus with

* ``SO_RCVBUF`` raised to ``rcvbuf`` bytes (``SO_RCVBUFFORCE`` first, which may exceed
  ``net.core.rmem_max`` with CAP_NET_ADMIN; else ``SO_RCVBUF``, capped by the kernel);
  :attr:`SocketcanRxBus.rcvbuf_bytes` is what the kernel granted (it doubles the request
  for its bookkeeping);
* ``SO_RXQ_OVFL`` on: each frame queued after a drop carries the socket's running drop
  count as a second control message. The frame is still decoded by python-can's own
  ``capture_message``, through :class:`_OverflowTap`, which hands it the timestamp alone and
  keeps the count (:attr:`SocketcanRxBus.kernel_drops`);
* a socket bound to an interface that is down is no connection: the kernel flags such a
  bind with ``ENETDOWN`` at once, and the bus then fails to open (so a reconnect attempt
  while ``ip link set vcan0 down`` holds is a failed attempt, not a reconnect).

The count reaches the reader with the first frame queued after the drop: frames already in
the buffer were queued before it. Linux only; imported only for the socketcan interface.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import struct
from typing import Any

import can
from can.interfaces.socketcan.socketcan import SocketcanBus, capture_message

SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
DEFAULT_RCVBUF = 8 * 1024 * 1024
"""Bytes asked for the receive buffer: about 9 000 frames at the ~900 bytes of kernel memory
a queued classic frame costs, 10 s of the board at 1 kHz, and the kernel doubles it."""

_TIMESTAMP = struct.Struct("@ll")
_DROPS = struct.Struct("@I")
_ANC_SPACE = socket.CMSG_SPACE(_TIMESTAMP.size) + socket.CMSG_SPACE(_DROPS.size)


class _OverflowTap:
    """Stands in for the bus socket in python-can's ``capture_message``: receives with room
    for both control messages, keeps the drop count and passes the rest on unchanged."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.drops = 0

    def recvmsg(
        self, bufsize: int, ancbufsize: int = 0, flags: int = 0
    ) -> tuple[bytes, list[tuple[int, int, bytes]], int, Any]:
        data, ancillary, msg_flags, address = self.sock.recvmsg(
            bufsize, max(ancbufsize, _ANC_SPACE), flags
        )
        rest = []
        for level, kind, payload in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(payload) >= _DROPS.size:
                # the socket's running count when this frame was queued (32 bits, may wrap)
                (count,) = _DROPS.unpack_from(payload)
                self.drops += (count - self.drops) % (1 << 32)
            else:
                rest.append((level, kind, payload))
        return data, rest, msg_flags, address


def set_receive_buffer(sock: socket.socket, size: int) -> int:
    """Ask for ``size`` bytes of receive buffer; returns what the kernel granted."""
    for option in (SO_RCVBUFFORCE, socket.SO_RCVBUF):
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, size)
            break
        except OSError:  # SO_RCVBUFFORCE without CAP_NET_ADMIN: EPERM
            continue
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


class SocketcanRxBus(SocketcanBus):
    """python-can's socketcan bus with a sized receive buffer and the kernel's drop count."""

    def __init__(self, channel: str = "", *, rcvbuf: int = DEFAULT_RCVBUF, **kwargs: Any) -> None:
        super().__init__(channel, **kwargs)
        try:
            pending = self.socket.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
            if pending:  # ENETDOWN: the interface exists but is down
                raise can.CanOperationError(
                    f"{channel}: {os.strerror(pending)} (interface down)", pending
                )
            self.rcvbuf_requested = int(rcvbuf)
            self.rcvbuf_bytes = set_receive_buffer(self.socket, self.rcvbuf_requested)
            self.socket.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
        except BaseException:
            with contextlib.suppress(Exception):
                self.shutdown()
            raise
        self._tap = _OverflowTap(self.socket)

    @property
    def kernel_drops(self) -> int:
        """Frames the kernel dropped at this socket (full receive buffer), as far as known."""
        return self._tap.drops

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            ready, _, _ = select.select([self.socket], [], [], timeout)
        except OSError as error:
            raise can.CanOperationError(
                f"Failed to receive: {error.strerror}", error.errno
            ) from error
        if not ready:
            return None, self._is_filtered
        # the tap stands in for the socket (recvmsg is all capture_message calls)
        msg = capture_message(self._tap, self.channel == "")  # type: ignore[arg-type]
        if msg is not None and not msg.channel and self.channel:
            msg.channel = self.channel
        return msg, self._is_filtered
