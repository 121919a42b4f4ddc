"""The live Foxglove stream as the commands use it: ``--foxglove [PORT]``, and the runner sink
that serves it from a writer process of its own (the server side is
:mod:`bench.mcaplog.foxglove_ws`)."""

from __future__ import annotations

import logging
from typing import Any

from bench.config import Config
from bench.errors import BenchError
from bench.mcaplog.foxglove_ws import DEFAULT_HOST, DEFAULT_PORT, stream_label

log = logging.getLogger("bench.foxglove")


def stream_sink(config: Config, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT) -> Any:
    """The live stream as a runner sink: the Foxglove server in a writer process of its own
    (idle priority, off the live CPU), fed like the MCAP log. A server that cannot start
    (port in use, bad address) is a one-line :class:`BenchError`."""
    from bench.mcaplog.writer_process import McapProcessSink

    sink = McapProcessSink(
        stream_label(host, port), config, sink="foxglove", host=host, port=int(port)
    )
    if sink.error:
        sink.close()
        reason = str(sink.error).split(": ", 1)[-1]
        raise BenchError(f"--foxglove: {reason}")
    log.info("Foxglove live stream on %s", sink.path)
    return sink


# -- the command line ----------------------------------------------------------------------------
def _port(text: str) -> int:
    import argparse

    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is not in 0..65535")
    return port


def add_foxglove_arguments(parser: Any) -> None:
    """``--foxglove [PORT]`` and ``--foxglove-host`` for the live commands."""
    parser.add_argument(
        "--foxglove",
        nargs="?",
        const=DEFAULT_PORT,
        default=None,
        type=_port,
        metavar="PORT",
        help=f"also serve the run live over the Foxglove WebSocket protocol (default port "
        f"{DEFAULT_PORT}; 0 picks a free one); open it in Foxglove with "
        "docs/foxglove/bench-layout.json",
    )
    parser.add_argument(
        "--foxglove-host",
        default=DEFAULT_HOST,
        metavar="HOST",
        help=f"address the Foxglove stream listens on (default {DEFAULT_HOST}: this machine only)",
    )


def open_stream(
    args: Any, config: Config, say: Any = None, metadata: dict[str, str] | None = None
) -> Any:
    """The live stream the command line asks for (None without ``--foxglove``), announced
    through ``say`` with the address a Foxglove client connects to; the address also goes
    into ``metadata`` as ``foxglove`` (the run's recordings state it: with ``--foxglove 0``
    the port is chosen here, and a TUI covers the line that said it)."""
    port = getattr(args, "foxglove", None)
    if port is None:
        return None
    host = getattr(args, "foxglove_host", DEFAULT_HOST) or DEFAULT_HOST
    sink = stream_sink(config, host, port)
    address = stream_label(host, sink.port)
    if metadata is not None:
        metadata["foxglove"] = address
    if say is not None:
        say(f"Foxglove live stream on {address}")
    return sink
