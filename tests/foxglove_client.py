"""A minimal Foxglove WebSocket protocol client for tests (the `websockets` package).

Written from the protocol spec (foxglove/ws-protocol docs/spec.md), not from the server's
code: connect offering the subprotocols, read serverInfo and advertise (JSON text), send
subscribe for every advertised channel, then count Message Data frames (binary: opcode 0x01,
uint32 subscription id, uint64 log time, payload; little-endian) per channel. Only ever
connects to 127.0.0.1.
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
