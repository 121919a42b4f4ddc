"""Both names of the Foxglove WebSocket protocol on one port, in front of the SDK's server.

foxglove-sdk 0.30 accepts a client only when it offers the subprotocol ``foxglove.sdk.v1``
and answers any other handshake with HTTP 400. The protocol is the same one that older
Foxglove Studio, Lichtblick and foxglove_bridge-era tools speak under its first name,
``foxglove.websocket.v1`` (Foxglove: the two are identical but for the name). So the SDK's
server listens on an ephemeral 127.0.0.1 port, and this front listens where the operator
asked: it reads a connection's HTTP upgrade request, and when the client offers only the old
name, asks the SDK with the new one and hands the answer back under the old one. The
``Sec-WebSocket-Accept`` key does not depend on the subprotocol, so the handshake stays
valid.

After the handshake the client's bytes pass to the SDK untouched. The SDK's bytes to the
client go through an outbox of the client's own, because a viewer that stops reading (a
frozen laptop, a hostile peer) must never hold the run: the front always reads what the
SDK sends, cuts it into WebSocket frames, and queues them for the client up to
``OUTBOX_BYTES``; a Message Data frame that does not fit is dropped and counted (the
protocol lets a viewer miss messages: it shows the next ones). Every other frame
(advertisements, status, control frames) is kept, up to ``OUTBOX_HARD_BYTES``. A client
that takes nothing for ``SEND_TIMEOUT_S`` while bytes wait for it, or whose outbox
passes the hard limit, is disconnected (reset, its unsent bytes freed) and counted.
Closing the front (once the SDK has stopped) lets each connection deliver its outbox and
ends every connection within ``CLOSE_TIMEOUT_S`` whatever the clients do.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
HEAD_LIMIT = 64 * 1024
"""An HTTP request head larger than this is no Foxglove client's: the connection is closed."""
CHUNK = 256 * 1024
OUTBOX_BYTES = 8 * 1024 * 1024
"""Bytes of Message Data queued per client before the newest messages are dropped: about
4 s of a 1 kHz run's stream (~2 MB/s with its 3 channels, results and health)."""
OUTBOX_HARD_BYTES = 4 * OUTBOX_BYTES
"""Bytes queued per client, of frames that cannot be dropped, before it is disconnected."""
SEND_TIMEOUT_S = 5.0
"""A client that takes no byte for this long while bytes wait for it is disconnected."""
SEND_BUFFER_BYTES = 256 * 1024
"""The kernel's send buffer for a client's socket: left to itself it grows to megabytes
that no outbox counts, and a stalled viewer would be noticed only after they filled."""
CLOSE_TIMEOUT_S = 5.0
HANDSHAKE_TIMEOUT_S = 10.0
"""A connection that has not sent its upgrade request (or got the SDK's answer) by then is
closed: a peer that opens connections and says nothing would otherwise keep each forever."""
MAX_CLIENTS = 16
"""Connections served at once; one more is answered 503 and counted (each stalled client
may hold an outbox of OUTBOX_BYTES for SEND_TIMEOUT_S: the bound keeps that sane)."""
BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\nConnection: close\r\n"
    b"Retry-After: 5\r\n\r\n"
)
"""How long closing the front waits for its connections to end."""
MESSAGE_DATA = 0x01
"""The first byte of a server's binary Message Data frame (Foxglove WebSocket protocol)."""


@dataclass
class ViewerCounts:
    """What slow clients cost, over every connection of the front."""

    messages_dropped: int = 0
    """Message Data frames a client's full outbox dropped."""
    clients_cut: int = 0
    """Clients disconnected: nothing taken for SEND_TIMEOUT_S, or the hard limit passed."""
    clients_refused: int = 0
    """Connections answered 503: MAX_CLIENTS were being served."""


def split_frames(buf: bytearray) -> list[tuple[bytes, bool]]:
    """Whole WebSocket frames at the start of ``buf`` (removed from it), each with whether
    it may be dropped: a complete, uncompressed binary Message Data frame (RFC 6455 framing;
    a compressed or fragmented message is never cut, its frames depend on each other)."""
    out: list[tuple[bytes, bool]] = []
    pos = 0
    while len(buf) - pos >= 2:
        b0, b1 = buf[pos], buf[pos + 1]
        n, head = b1 & 0x7F, 2
        if n == 126:
            if len(buf) - pos < 4:
                break
            n, head = struct.unpack_from(">H", buf, pos + 2)[0], 4
        elif n == 127:
            if len(buf) - pos < 10:
                break
            n, head = struct.unpack_from(">Q", buf, pos + 2)[0], 10
        if b1 & 0x80:
            head += 4  # a masking key (servers do not mask; counted if one did)
        end = pos + head + n
        if len(buf) < end:
            break
        first = buf[pos + head] if n else -1
        droppable = b0 == 0x82 and first == MESSAGE_DATA and not b1 & 0x80  # FIN, binary
        out.append((bytes(buf[pos:end]), droppable))
        pos = end
    del buf[:pos]
    return out


def _is_protocol(line: bytes) -> bool:
    return line.split(b":", 1)[0].strip().lower() == b"sec-websocket-protocol"


def _offered(head: bytes) -> list[str]:
    """The subprotocols a request head offers (every Sec-WebSocket-Protocol line)."""
    return [
        token.strip().decode("latin-1")
        for line in head.split(b"\r\n")[1:]
        if _is_protocol(line)
        for token in line.split(b":", 1)[1].split(b",")
        if token.strip()
    ]


def rewrite_request(head: bytes) -> tuple[bytes, bool]:
    """The request head to send the SDK, and whether the client offered only the old name
    (so the answer must be renamed back)."""
    offered = _offered(head)
    if SDK_SUBPROTOCOL in offered or LEGACY_SUBPROTOCOL not in offered:
        return head, False  # as it is: the SDK accepts it, or refuses it as it should
    lines: list[bytes] = []
    for line in head.split(b"\r\n"):
        if _is_protocol(line):
            if any(_is_protocol(kept) for kept in lines):
                continue
            line = b"Sec-WebSocket-Protocol: " + SDK_SUBPROTOCOL.encode()
        lines.append(line)
    return b"\r\n".join(lines), True


def rewrite_response(head: bytes) -> bytes:
    """The SDK's answer with the subprotocol named as the client asked for it."""
    return b"\r\n".join(
        b"Sec-WebSocket-Protocol: " + LEGACY_SUBPROTOCOL.encode() if _is_protocol(line) else line
        for line in head.split(b"\r\n")
    )


class SubprotocolFront:
    """Listens on ``host:port`` (0: a free port, then in ``port``) and relays every
    connection to the SDK server on ``127.0.0.1:inner_port``, from an event loop in a
    daemon thread of its own."""

    def __init__(self, host: str, port: int, inner_port: int) -> None:
        self.inner_port = inner_port
        self.counts = ViewerCounts()
        self.last_read = time.monotonic()  # when bytes last came from the SDK (any client)
        self._loop = asyncio.new_event_loop()
        self._tasks: set[asyncio.Task[None]] = set()
        try:
            self._server = self._loop.run_until_complete(
                asyncio.start_server(self._serve, host, port, limit=HEAD_LIMIT)
            )
        except BaseException:
            self._loop.close()
            raise
        self.port = int(self._server.sockets[0].getsockname()[1])
        self._thread = threading.Thread(
            target=self._loop.run_forever, name="foxglove-front", daemon=True
        )
        self._thread.start()

    def close(self) -> None:
        if self._loop.is_closed():
            return

        async def shut() -> None:
            # the SDK has stopped: each connection ends once its outbox is delivered (a
            # stalled client is let go by the send timeout); what is left is cancelled
            self._server.close()
            if self._tasks:
                await asyncio.wait(list(self._tasks), timeout=CLOSE_TIMEOUT_S)
            for task in list(self._tasks):
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)

        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(shut(), self._loop).result(CLOSE_TIMEOUT_S + 1)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(CLOSE_TIMEOUT_S)
        if not self._thread.is_alive():
            self._loop.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        upstream: asyncio.StreamWriter | None = None
        sock = writer.get_extra_info("socket")
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        try:
            if len(self._tasks) > MAX_CLIENTS:
                self.counts.clients_refused += 1
                writer.write(BUSY)
                await asyncio.wait_for(writer.drain(), SEND_TIMEOUT_S)
                return
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
            head, legacy = rewrite_request(head)
            up_reader, upstream = await asyncio.open_connection(
                "127.0.0.1", self.inner_port, limit=HEAD_LIMIT
            )
            upstream.write(head)
            await upstream.drain()
            answer = await asyncio.wait_for(up_reader.readuntil(b"\r\n\r\n"), HANDSHAKE_TIMEOUT_S)
            writer.write(rewrite_response(answer) if legacy else answer)
            await writer.drain()
            if answer.startswith(b"HTTP/1.1 101"):  # WebSocket frames from here on
                await _until(self._outbox(up_reader, writer), _pipe(reader, upstream))
            else:  # the SDK's refusal (400): its body, then the end
                await _until(_pipe(up_reader, writer), _pipe(reader, upstream))
        except (OSError, TimeoutError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
            pass  # a client that went away, said nothing in time or was not one
        except asyncio.CancelledError:
            pass  # the front is closing (a connection's task ends quietly: nothing awaits it)
        except _SlowClient:
            self.counts.clients_cut += 1  # it took nothing for SEND_TIMEOUT_S: let it go
            _reset(writer)
        finally:
            for w in (writer, upstream):
                if w is not None:
                    with contextlib.suppress(Exception):
                        w.close()
            self._tasks.discard(task)

    async def _outbox(self, src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
        """The SDK's frames to one client: read as they come, queued (Message Data
        dropped beyond ``OUTBOX_BYTES``), written with a send timeout."""
        box = _Outbox(self)
        reading = asyncio.ensure_future(box.take(src))
        try:
            await box.give(dst)
        finally:
            reading.cancel()
            with contextlib.suppress(asyncio.CancelledError, OSError):
                await reading


def _reset(writer: asyncio.StreamWriter) -> None:
    """End a connection at once with a reset: a close would queue its FIN behind bytes a
    peer that never reads never takes, and the kernel would keep them (and the peer would
    never learn it was let go)."""
    sock = writer.get_extra_info("socket")
    if sock is not None:
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    writer.transport.abort()


class _Outbox:
    """One client's queue of frames from the SDK (see the module's docstring)."""

    def __init__(self, front: SubprotocolFront) -> None:
        self.front = front
        self.counts = front.counts
        self.frames: deque[bytes] = deque()
        self.queued = 0  # bytes in ``frames``
        self.ready = asyncio.Event()
        self.ended = False  # the SDK closed its side
        self.over = False  # the hard limit was passed

    async def take(self, src: asyncio.StreamReader) -> None:
        buf = bytearray()
        try:
            while not self.over and (data := await src.read(CHUNK)):
                self.front.last_read = time.monotonic()
                buf += data
                for frame, droppable in split_frames(buf):
                    if droppable and self.queued + len(frame) > OUTBOX_BYTES:
                        self.counts.messages_dropped += 1
                        continue
                    self.frames.append(frame)
                    self.queued += len(frame)
                self.over = self.queued > OUTBOX_HARD_BYTES
                self.ready.set()
        finally:
            self.ended = True
            self.ready.set()

    async def give(self, dst: asyncio.StreamWriter) -> None:
        while True:
            await self.ready.wait()
            self.ready.clear()
            while self.frames and not self.over:
                batch: list[bytes] = []
                size = 0
                while self.frames and size < CHUNK:
                    batch.append(self.frames.popleft())
                    size += len(batch[-1])
                self.queued -= size
                dst.write(b"".join(batch))
                await _drain(dst)
            if self.over:
                raise _SlowClient
            if self.ended:
                with contextlib.suppress(Exception):
                    if dst.can_write_eof():
                        dst.write_eof()
                return


async def _drain(dst: asyncio.StreamWriter) -> None:
    """Wait until the client has taken what was written (below the transport's high-water
    mark); :class:`_SlowClient` when it took nothing at all for ``SEND_TIMEOUT_S``. A client
    on a slow link that keeps taking bytes is waited for (what it cannot take meanwhile is
    dropped from its outbox), never cut."""
    left = dst.transport.get_write_buffer_size()
    while True:
        try:
            await asyncio.wait_for(dst.drain(), SEND_TIMEOUT_S)
            return
        except TimeoutError:
            now = dst.transport.get_write_buffer_size()
            if now >= left:
                raise _SlowClient from None
            left = now  # it took some: wait on


class _SlowClient(Exception):
    """A client that took nothing for SEND_TIMEOUT_S, or whose outbox passed the limit."""


async def _until(to_client: Any, from_client: Any) -> None:
    """Run the two directions of a connection until the SDK's side has been delivered
    (the SDK closed: the connection is over, whatever the client still sends) or either
    fails; the failure ends the other (``asyncio.gather`` would leave it running) and its
    exception goes on."""
    tasks = [asyncio.ensure_future(to_client), asyncio.ensure_future(from_client)]
    try:
        while not tasks[0].done():
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for task in done:
                if not task.cancelled() and (exc := task.exception()) is not None:
                    raise exc
            if tasks[1].done() and not tasks[0].done():
                await tasks[0]  # the client stopped sending: the SDK's side still goes out
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


async def _pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
    """Bytes from ``src`` to ``dst`` until ``src`` ends; then ``dst``'s writing side ends."""
    try:
        while data := await src.read(CHUNK):
            dst.write(data)
            await dst.drain()
    finally:
        with contextlib.suppress(Exception):
            if dst.can_write_eof():
                dst.write_eof()
