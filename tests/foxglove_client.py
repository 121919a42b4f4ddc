"""A minimal Foxglove WebSocket protocol client for tests (the `websockets` package).

Written from the protocol spec (foxglove/ws-protocol docs/spec.md), not from the server's
code: connect offering the subprotocols, read serverInfo and advertise (JSON text), send
subscribe for every advertised channel (and for each one advertised later), then count
Message Data frames (binary: opcode 0x01, uint32 subscription id, uint64 log time, payload;
little-endian) per channel. Only ever connects to 127.0.0.1.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import struct
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

SUBPROTOCOLS = ("foxglove.websocket.v1", "foxglove.sdk.v1")
"""What the Foxglove app offers: the spec's name and the SDK's name for the same protocol."""
MESSAGE_DATA = 0x01


@dataclass
class Received:
    subprotocol: str | None = None
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  # id -> advertisement
    subscribed: bool = False
    messages: dict[str, list[tuple[int, bytes]]] = field(
        default_factory=lambda: defaultdict(list)
    )  # topic -> (log time ns, payload)
    errors: list[str] = field(default_factory=list)

    def counts(self) -> dict[str, int]:
        return {topic: len(m) for topic, m in self.messages.items()}


class Client:
    """Runs the protocol on a thread of its own; ``received`` fills in as messages come."""

    def __init__(
        self, port: int, *, settle_s: float = 0.5, subprotocols: tuple[str, ...] = SUBPROTOCOLS
    ) -> None:
        self.port = port
        self.subprotocols = subprotocols
        self.settle_s = settle_s
        self.received = Received()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._main, name="ws-client", daemon=True)

    def start(self, timeout: float = 20.0) -> Client:
        self._thread.start()
        deadline = time.monotonic() + timeout
        while not self.received.subscribed and time.monotonic() < deadline:
            if self.received.errors:
                raise AssertionError(f"client failed: {self.received.errors}")
            time.sleep(0.02)
        assert self.received.subscribed, "the client did not subscribe in time"
        return self

    def stop(self, timeout: float = 10.0) -> Received:
        self._stop.set()
        self._thread.join(timeout)
        return self.received

    def wait_quiet(self, quiet_s: float = 1.0, timeout: float = 60.0) -> Received:
        """Until no message arrived for ``quiet_s`` (the server has sent all it had)."""
        deadline = time.monotonic() + timeout
        last = -1
        stable_since = time.monotonic()
        while time.monotonic() < deadline:
            n = sum(self.received.counts().values())
            if n != last:
                last, stable_since = n, time.monotonic()
            elif time.monotonic() - stable_since >= quiet_s:
                break
            time.sleep(0.05)
        return self.received

    def _main(self) -> None:
        try:
            asyncio.run(self._run())
        except Exception as exc:  # reported to the test, never swallowed
            self.received.errors.append(repr(exc))

    async def _run(self) -> None:
        import websockets

        r = self.received
        async with websockets.connect(
            f"ws://127.0.0.1:{self.port}",
            subprotocols=list(self.subprotocols),  # type: ignore[arg-type]
            proxy=None,
            max_size=None,
        ) as ws:
            r.subprotocol = ws.subprotocol
            subs: dict[int, int] = {}  # subscription id -> channel id
            # the server sends serverInfo, then advertise for its channels; collect until quiet
            deadline = time.monotonic() + self.settle_s
            while time.monotonic() < deadline or not r.channels:
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    if time.monotonic() > deadline + 10:
                        break
                    continue
                self._text(msg)
            for sub_id, cid in enumerate(sorted(r.channels)):
                subs[sub_id] = cid
            await ws.send(
                json.dumps(
                    {
                        "op": "subscribe",
                        "subscriptions": [{"id": s, "channelId": c} for s, c in subs.items()],
                    }
                )
            )
            r.subscribed = True
            while not self._stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), 0.2)
                except TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    break
                if isinstance(msg, bytes):
                    if msg[0] != MESSAGE_DATA:
                        continue
                    sub_id, log_time = struct.unpack_from("<IQ", msg, 1)
                    topic = r.channels[subs[sub_id]]["topic"]
                    r.messages[topic].append((log_time, bytes(msg[13:])))
                else:
                    self._text(msg)
                    # a channel advertised later (the live model's, with its first row): a
                    # viewer showing it subscribes then, as Foxglove's panels do
                    late = sorted(set(r.channels) - set(subs.values()))
                    if late:
                        first = len(subs)
                        subs.update({first + k: cid for k, cid in enumerate(late)})
                        new = [{"id": first + k, "channelId": c} for k, c in enumerate(late)]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            with contextlib.suppress(Exception):
                await ws.close()

    def _text(self, msg: str | bytes) -> None:
        if isinstance(msg, bytes):
            return
        d = json.loads(msg)
        if d.get("op") == "serverInfo":
            self.received.server_info = d
        elif d.get("op") == "advertise":
            for c in d.get("channels", []):
                self.received.channels[int(c["id"])] = c


class StalledClient:
    """A viewer that subscribes to every channel and then never reads again: a raw socket
    with a 4 KiB receive buffer (the kernel's window then closes after a few frames), the
    WebSocket handshake and frames written by hand from RFC 6455 (client frames masked).
    What a Foxglove app frozen by the operator's laptop, or a hostile peer, does to a run."""

    def __init__(self, port: int, subprotocol: str = SUBPROTOCOLS[0]) -> None:
        import base64
        import os
        import socket

        self.port = port
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        self.sock.settimeout(30.0)
        self.sock.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {subprotocol}\r\n\r\n"
            ).encode()
        )
        self._buf = b""
        while b"\r\n\r\n" not in self._buf:
            data = self.sock.recv(4096)
            assert data, "the server closed the connection during the handshake"
            self._buf += data
        head, self._buf = self._buf.split(b"\r\n\r\n", 1)
        self.status = head.split(b"\r\n", 1)[0].decode()
        self.channels: dict[int, str] = {}

    def _frame(self) -> tuple[int, bytes]:
        """The next whole server frame (opcode, payload); server frames are unmasked."""
        while True:
            buf = self._buf
            if len(buf) >= 2:
                n, off = buf[1] & 0x7F, 2
                if n == 126 and len(buf) >= 4:
                    n, off = struct.unpack(">H", buf[2:4])[0], 4
                elif n == 127 and len(buf) >= 10:
                    n, off = struct.unpack(">Q", buf[2:10])[0], 10
                if (n < 126 or off > 2) and len(buf) >= off + n:
                    self._buf = buf[off + n :]
                    return buf[0] & 0x0F, buf[off : off + n]
            data = self.sock.recv(65536)
            assert data, "the server closed the connection"
            self._buf += data

    def subscribe(self, topic: str = "/can/frames") -> StalledClient:
        """Read the advertisements until ``topic`` is offered, subscribe to every channel
        offered so far, and from then on read nothing."""
        import os

        while topic not in self.channels.values():
            opcode, payload = self._frame()
            if opcode == 0x1:
                msg = json.loads(payload)
                if msg.get("op") == "advertise":
                    self.channels.update({int(c["id"]): c["topic"] for c in msg["channels"]})
        text = json.dumps(
            {
                "op": "subscribe",
                "subscriptions": [{"id": i, "channelId": c} for i, c in enumerate(self.channels)],
            }
        ).encode()
        mask = os.urandom(4)
        head = bytes([0x81, 0x80 | 126]) + struct.pack(">H", len(text))
        if len(text) < 126:
            head = bytes([0x81, 0x80 | len(text)])
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(text)))
        return self

    def was_let_go(self) -> bool:
        """Whether the server ended the connection (its reset or close arrived), seen from
        the kernel's TCP state without reading a byte (Linux ``TCP_INFO``)."""
        import socket

        info = self.sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 8)
        return info[0] != 1  # tcpi_state: 1 is TCP_ESTABLISHED

    def close(self) -> None:
        self.sock.close()
