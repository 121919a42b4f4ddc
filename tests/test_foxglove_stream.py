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
from bench.mcaplog.foxglove_stream import stream_sink
from bench.mcaplog.sink import McapSink
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


ROOT = Path(__file__).resolve().parent.parent


def test_bench_run_foxglove_serves_the_topics_of_its_own_log(tmp_path: Path) -> None:
    """`bench run --emulate ... --foxglove 0`: the stream of a real run. A client connects
    when the command prints the address, so it misses the first moments; what it receives
    must be exactly the end of each topic in the MCAP file the same run wrote."""
    import re
    import subprocess
    import sys
    import time

    path = tmp_path / "run.mcap"
    cmd = [sys.executable, "-m", "bench", "run", "--emulate", "level_run", "--duration", "5"]
    cmd += ["--mcap", str(path), "--foxglove", "0", "--quiet"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, text=True)
    assert proc.stderr is not None
    port = None
    lines = []
    deadline = time.monotonic() + 60
    while port is None and time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"Foxglove live stream on ws://127\.0\.0\.1:(\d+)", line)
        if m:
            port = int(m.group(1))
    assert port, "".join(lines)
    client = Client(port).start()
    rest = proc.communicate(timeout=120)[1]
    client.wait_quiet(quiet_s=1.0)
    got = client.stop()
    assert proc.returncode == 0, "".join(lines) + rest
    assert "Traceback" not in rest
    channels, messages = mcap_contents(path)
    advertised = {c["topic"]: (c["encoding"], c["schemaName"]) for c in got.channels.values()}
    assert advertised == channels
    for topic in ("/can/frames", "/bench/results", "/bench/samples", "/bench/status"):
        received = got.messages.get(topic, [])
        assert len(received) > 100 or (topic == "/bench/status" and received), topic
    for topic, expected in messages.items():
        received = got.messages.get(topic, [])
        assert len(received) <= len(expected), topic
        if received:
            assert received == expected[-len(received) :], topic  # the file's own tail


def test_foxglove_binds_this_machine_only_by_default() -> None:
    import argparse

    from bench.mcaplog.foxglove_stream import add_foxglove_arguments
    from bench.mcaplog.foxglove_ws import DEFAULT_HOST

    p = argparse.ArgumentParser()
    add_foxglove_arguments(p)
    assert p.parse_args([]).foxglove is None
    args = p.parse_args(["--foxglove"])
    assert (args.foxglove, args.foxglove_host) == (
        8765,
        "127.0.0.1",
    ) and args.foxglove_host == DEFAULT_HOST
    assert p.parse_args(["--foxglove", "9000"]).foxglove == 9000
    with pytest.raises(SystemExit):
        p.parse_args(["--foxglove", "70000"])


def test_tui_foxglove_streams_from_the_engine_process(tmp_path: Path) -> None:
    """`bench tui --emulate ... --foxglove 0`: the stream is built in the engine process,
    beside the recording, and announced before the screen opens."""
    import re

    from bench.cli import build_parser
    from bench.engine.client import start_engine
    from bench.engine.plans import LivePlan, cli_values

    args = build_parser().parse_args(
        ["tui", "--emulate", "level_run", "--foxglove", "0", "--mcap", str(tmp_path / "t.mcap")]
    )
    said: list[str] = []
    session = start_engine(
        LivePlan(config=Config(), args=cli_values(args), log_dir=tmp_path), warn=said.append
    )
    try:
        found = [m for line in said if (m := re.search(r"ws://127\.0\.0\.1:(\d+)", line))]
        assert found, said
        client = Client(int(found[0].group(1))).start()
        client.wait_quiet(quiet_s=0.1, timeout=3.0)
        deadline = 30.0
        import time

        end = time.monotonic() + deadline
        while len(client.received.messages.get("/bench/results", [])) < 50:
            assert time.monotonic() < end, client.received.counts()
            time.sleep(0.1)
        got = client.stop()
        assert {c["topic"] for c in got.channels.values()} >= {"/bench/results", "/can/frames"}
    finally:
        session.stop()
    assert session.report is not None and session.report.error is None
