"""The live Foxglove stream: a run's MCAP topics served over the Foxglove WebSocket protocol.

Why this shape: Foxglove should show a live run exactly as it later shows the run's MCAP
file, with the same layout (docs/foxglove/bench-layout.json). So the stream is not a second
encoder: :class:`WsChannels` offers the part of :class:`~bench.mcaplog.file.McapFile`'s
interface the :class:`~bench.mcaplog.encoder.MessageEncoder` writes to (schemas, channels,
messages) on a foxglove-sdk WebSocket server, and :class:`FoxgloveSink` is the MCAP sink's
very code (events, health every second, marks, drop events) writing into it. Same topics,
same schemas, same messages, same counts.

The receive path never waits on it: like the MCAP log it runs in a writer process of its own
at idle priority, off the live CPU (:func:`bench.mcaplog.foxglove_stream.stream_sink`), fed
from the runner's sinks (the
processing thread only enqueues; a full queue drops the step and counts it in ``dropped``).
A viewer never holds the run: between the SDK and each client the front keeps a bounded
outbox of the client's own that drops (and counts) Message Data for a client that falls
behind, and disconnects one that takes nothing for a few seconds
(:mod:`bench.mcaplog.foxglove_front`); what slow viewers cost comes back in
``viewer_counts`` and is warned once at the end of the run.

The SDK (0.30) speaks the protocol under the subprotocol name ``foxglove.sdk.v1`` only, the
same protocol as ``foxglove.websocket.v1`` renamed; the Foxglove app offers both, older
Foxglove Studio, Lichtblick and foxglove_bridge-era tools only the old one. So the SDK's
server listens on 127.0.0.1 at a free port and :class:`~bench.mcaplog.foxglove_front.
SubprotocolFront` on the address asked for, accepting both names.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.config import Config
from bench.mcaplog.foxglove_front import SubprotocolFront

log = logging.getLogger("bench.foxglove")

DEFAULT_HOST = "127.0.0.1"
INNER_HOST = "127.0.0.1"
"""Where the SDK's own server listens (a free port): only the front connects to it."""
DEFAULT_PORT = 8765
BACKLOG = 65_536
"""Messages the SDK buffers per client: a 0.25 s group at 1 kHz x 3 channels is ~5 000."""
SERVER_NAME = "gradient bench"
STOP_TIMEOUT_S = 5.0
"""How long stopping the SDK's server may wait for its clients (see WsChannels.abort)."""
LINGER_S = 0.5
"""How long the server stays up after the last message of a run (see WsChannels.finish)."""
LINGER_MAX_S = 3.0
"""The longest the server stays up after a run while the SDK is still sending (the
writer process is given 10 s to end: this, the SDK's stop and the front's close fit)."""


def stream_label(host: str, port: int) -> str:
    return f"ws://{host}:{port}"


class WsChannels:
    """What :class:`MessageEncoder` needs of an MCAP file, on a foxglove-sdk WebSocket server:
    schemas, channels and messages go out to subscribed clients as they come. Counts per
    channel are kept (``written``) so the sink's figures read as for a file."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT) -> None:
        import foxglove

        self._fg = foxglove
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name=SERVER_NAME,
                host=INNER_HOST,
                port=0,
                context=self.context,
                message_backlog_size=BACKLOG,
            )
        except Exception as exc:  # the SDK raises its own error types
            raise OSError(f"cannot start the Foxglove server: {exc}") from None
        try:  # where clients connect: both names of the protocol (foxglove_front)
            self.front = SubprotocolFront(host, port, int(self.server.port))
        except (OSError, ValueError) as exc:  # a port in use, an address not of this machine
            self.server.stop()
            why = getattr(exc, "strerror", None) or exc
            raise OSError(f"cannot serve Foxglove on {stream_label(host, port)}: {why}") from None
        self.host = host
        self.port = self.front.port
        self._schemas: list[Any] = []
        self._channels: list[Any] = []
        self._counts: Counter[int] = Counter()
        self.position = 0  # payload bytes handed to the server
        self.pending_messages = 0  # nothing is held back: every message goes out at once
        self.closed = False

    # -- McapFile's message interface ------------------------------------------------------
    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        self._schemas.append(self._fg.Schema(name=name, encoding=encoding, data=bytes(data)))
        return len(self._schemas)

    def add_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: Mapping[str, str] | None = None,
        *,
        lane: int = 0,
    ) -> int:
        channel = self._fg.Channel(
            topic,
            schema=self._schemas[schema_id - 1],
            message_encoding=message_encoding,
            context=self.context,
            metadata=dict(metadata or {}),
        )
        self._channels.append(channel)
        return len(self._channels)

    def add_fixed_records(self, channel_id: int, records: np.ndarray) -> None:
        """Complete MCAP Message records of one size: their payloads go out one by one."""
        if not len(records):
            return
        payload = records["payload"]
        raw = payload.tobytes()
        size = payload.dtype.itemsize
        self._log(channel_id, records["log_time"].tolist(), raw, size)

    def add_messages(
        self,
        channel_id: int,
        log_times: np.ndarray,
        payloads: Sequence[bytes],
        sequences: Sequence[int] | np.ndarray,
    ) -> None:
        base = self._channels[channel_id - 1].base
        for lt, payload in zip(np.asarray(log_times).tolist(), payloads, strict=True):
            base.log(payload, int(lt))
            self.position += len(payload)
        self._counts[channel_id] += len(payloads)

    def _log(self, channel_id: int, log_times: list[int], raw: bytes, size: int) -> None:
        base = self._channels[channel_id - 1].base
        view = memoryview(raw)
        for i, lt in enumerate(log_times):
            base.log(bytes(view[i * size : (i + 1) * size]), int(lt))
        self.position += len(raw)
        self._counts[channel_id] += len(log_times)

    def written(self, channel_id: int) -> int:
        return self._counts[channel_id]

    # -- the rest of the file interface: a stream has no metadata, chunks or summary ---------
    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        pass

    def add_attachment(
        self, name: str, data: bytes, media_type: str = "", log_time: int = 0
    ) -> None:
        pass

    def maybe_flush(self) -> int:
        return 0

    def flush_chunk(self) -> int:
        return 0

    def flush_io(self) -> None:
        pass

    def finish(self) -> None:
        """The run is over: let the SDK hand its last messages (the final health snapshot)
        to the front, which then delivers them: until nothing has come from the SDK for
        ``LINGER_S`` (at most ``LINGER_MAX_S``; the SDK drops what it still holds when it
        stops, and at idle priority under load it can take seconds), then stop the server."""
        if not self.closed:
            deadline = time.monotonic() + LINGER_MAX_S
            time.sleep(LINGER_S)
            while time.monotonic() < deadline:
                if time.monotonic() - self.front.last_read >= LINGER_S:
                    break  # quiet: the SDK has handed over everything
                time.sleep(0.05)
        self.abort()

    def abort(self) -> None:
        """Stop the SDK's server, then the front. The SDK's ``stop`` waits for its clients:
        the front always reads, but a local process that connected to the SDK's own port
        and stalled held it forever; so it gets ``STOP_TIMEOUT_S`` in a thread of its own
        (the thread does not hold the process's exit)."""
        if not self.closed:
            self.closed = True

            def stop() -> None:
                with contextlib.suppress(Exception):
                    self.server.stop()

            stopping = threading.Thread(target=stop, name="foxglove-stop", daemon=True)
            stopping.start()
            stopping.join(STOP_TIMEOUT_S)
            self.front.close()


def foxglove_sink_class() -> type:
    """:class:`FoxgloveSink`, built on the MCAP sink (imported late: the writer process
    imports this module before it knows which sink it runs)."""
    from bench.mcaplog.sink import McapSink

    class FoxgloveSink(McapSink):
        """The MCAP sink's code writing into :class:`WsChannels` instead of a file."""

        def __init__(
            self,
            config: Config,
            metadata: Mapping[str, str] | None = None,
            attachments: Sequence[tuple[str, bytes]] = (),
            *,
            host: str = DEFAULT_HOST,
            port: int = DEFAULT_PORT,
            **options: Any,
        ) -> None:
            self.host, self.port = host, int(port)
            options.pop("compression", None)
            super().__init__(stream_label(host, port), config, metadata, attachments, **options)

        def _open_file(self, chunk_size: int, compression: str) -> Any:
            ws = self._ws = WsChannels(self.host, self.port)
            self.port = ws.port
            self.path = Path(stream_label(self.host, ws.port))
            return ws

        def viewer_counts(self) -> dict[str, int]:
            """What slow viewers cost so far (messages dropped, clients disconnected)."""
            ws = getattr(self, "_ws", None)
            return {} if ws is None else dataclasses.asdict(ws.front.counts)

    return FoxgloveSink
