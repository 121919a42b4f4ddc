"""The live Foxglove stream (--foxglove) against the MCAP file of the same run: a WebSocket
client on 127.0.0.1 subscribes per the protocol spec; the channels it is offered must be the
MCAP file's (topic, encoding, schema name) and the messages it receives must be the MCAP
file's, topic by topic: the same count, the same log times, the same bytes."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import pytest
from mcap.reader import make_reader

from bench.config import Config
from bench.errors import BenchError
from bench.mcaplog.foxglove_ws import stream_sink
from bench.mcaplog.writer import McapSink
from devices.base import SourceBatch
from tests.foxglove_client import SUBPROTOCOLS, Client
from tests.test_mcap_support import emulated, run_pipeline


def mcap_contents(
    path: Path,
) -> tuple[dict[str, tuple[str, str]], dict[str, list[tuple[int, bytes]]]]:
    """Channels (topic -> (message encoding, schema name)) and messages per topic."""
    channels: dict[str, tuple[str, str]] = {}
    messages: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
    with path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        for ch in summary.channels.values():
            schema = summary.schemas[ch.schema_id]
            channels[ch.topic] = (ch.message_encoding, schema.name)
        for _schema, ch, msg in reader.iter_messages(log_time_order=False):
            messages[ch.topic].append((msg.log_time, bytes(msg.data)))
    return channels, messages


def test_stream_carries_exactly_the_mcap_files_messages(tmp_path: Path) -> None:
    config = Config()
    stream = stream_sink(config, port=0)  # an ephemeral port on 127.0.0.1
    try:
        assert stream.port and stream.port > 0
        client = Client(stream.port).start()  # subscribed before the run begins
        path = tmp_path / "run.mcap"
        mcap = McapSink(path, config)
        sim = emulated(14.0)  # every fault kind: events of every sort, health, status
        step = 450
        batches = [SourceBatch(sim.frames[i : i + step]) for i in range(0, len(sim.frames), step)]
        run_pipeline(batches, config, sinks=[mcap, stream])
        for sink in (mcap, stream):
            sink.mark(float(sim.frames["t"][-1]), "operator mark 1")
        mcap.close()
        stream.close()  # the final health snapshot goes out, then the server stops
        client.wait_quiet(quiet_s=1.0)
    finally:
        stream.close()
    got = client.stop()
    assert not got.errors
    assert got.subprotocol in SUBPROTOCOLS
    channels, messages = mcap_contents(path)
    advertised = {c["topic"]: (c["encoding"], c["schemaName"]) for c in got.channels.values()}
    assert advertised == channels
    assert stream.dropped == 0 and mcap.dropped == 0
    for topic, expected in messages.items():
        received = got.messages.get(topic, [])
        assert len(received) == len(expected), topic
        assert received == expected, topic  # same log times, same bytes, same order
    assert len(messages["/can/frames"]) == len(sim.frames)
    assert any(b"operator mark 1" in m for _, m in got.messages["/bench/events"])


def test_a_port_in_use_is_one_line_error() -> None:
    first = stream_sink(Config(), port=0)
    try:
        with pytest.raises(BenchError, match="--foxglove"):
            stream_sink(Config(), port=first.port)
    finally:
        first.close()
