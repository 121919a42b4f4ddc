"""Both names of the Foxglove WebSocket protocol on one port, in front of the SDK's server.

foxglove-sdk 0.30 accepts a client only when it offers the subprotocol ``foxglove.sdk.v1``
and answers any other handshake with HTTP 400. The protocol is the same one that older
Foxglove Studio, Lichtblick and foxglove_bridge-era tools speak under its first name,
``foxglove.websocket.v1`` (Foxglove: the two are identical but for the name). So the SDK's
server listens on an ephemeral 127.0.0.1 port, and this front listens where the operator
asked: it reads a connection's HTTP upgrade request, and when the client offers only the old
name, asks the SDK with the new one and hands the answer back under the old one. The
``Sec-WebSocket-Accept`` key does not depend on the subprotocol, so the handshake stays
valid; after it, bytes pass both ways untouched.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
HEAD_LIMIT = 64 * 1024
"""An HTTP request head larger than this is no Foxglove client's: the connection is closed."""
CHUNK = 256 * 1024


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
            self._server.close()
            for task in list(self._tasks):
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)

        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(shut(), self._loop).result(5)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        if not self._thread.is_alive():
            self._loop.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tasks.add(task)
        upstream: asyncio.StreamWriter | None = None
        try:
            head = await reader.readuntil(b"\r\n\r\n")
            head, legacy = rewrite_request(head)
            up_reader, upstream = await asyncio.open_connection(
                "127.0.0.1", self.inner_port, limit=HEAD_LIMIT
            )
            upstream.write(head)
            await upstream.drain()
            if legacy:
                writer.write(rewrite_response(await up_reader.readuntil(b"\r\n\r\n")))
                await writer.drain()
            await asyncio.gather(_pipe(reader, upstream), _pipe(up_reader, writer))
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
            pass  # a client that went away or was not one: nothing to serve
        finally:
            for w in (writer, upstream):
                if w is not None:
                    with contextlib.suppress(Exception):
                        w.close()
            self._tasks.discard(task)


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
