"""The live Foxglove stream (--foxglove) against the MCAP file of the same run: a WebSocket
client on 127.0.0.1 subscribes per the protocol spec; the channels it is offered must be the
MCAP file's (topic, encoding, schema name) and the messages it receives must be the MCAP
file's, topic by topic: the same count, the same log times, the same bytes."""

from __future__ import annotations

import asyncio
from collections import defaultdict
from pathlib import Path
from typing import Any

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
    """`bench run --emulate ... --foxglove 0 --lag 0.5`: the stream of a real run, the live
    model's /bench/model topic included. A client connects
    when the command prints the address, so it misses the first moments; what it receives
    must be exactly the end of each topic in the MCAP file the same run wrote."""
    import re
    import subprocess
    import sys
    import time

    path = tmp_path / "run.mcap"
    cmd = [sys.executable, "-m", "bench", "run", "--emulate", "level_run", "--duration", "5"]
    cmd += ["--mcap", str(path), "--foxglove", "0", "--quiet", "--lag", "0.5"]  # + the model
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
    assert run_record(path)["foxglove"] == f"ws://127.0.0.1:{port}"  # the chosen port, kept
    channels, messages = mcap_contents(path)
    advertised = {c["topic"]: (c["encoding"], c["schemaName"]) for c in got.channels.values()}
    assert advertised == channels
    assert "/bench/model" in channels  # the live model's rows (--lag), added with the first
    for topic in ("/can/frames", "/bench/results", "/bench/samples", "/bench/status"):
        received = got.messages.get(topic, [])
        assert len(received) > 100 or (topic == "/bench/status" and received), topic
    assert len(got.messages.get("/bench/model", [])) > 10  # 20 ms blocks over seconds
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
        # --foxglove 0: the chosen port where the operator looks once the screen is up
        address = f"ws://127.0.0.1:{found[0].group(1)}"
        assert session.snapshot().extra["foxglove"] == address
    finally:
        session.stop()
    assert session.report is not None and session.report.error is None
    assert run_record(tmp_path / "t.mcap")["foxglove"] == address  # and in the log


def run_record(path: Path) -> dict[str, str]:
    from bench.mcaplog.reader import McapLog

    with McapLog(path) as log:
        return log.metadata_dict()["run"]


def test_the_recording_panel_shows_the_stream_address() -> None:
    import io

    from rich.console import Console

    from bench.tui.panels.recording import recording_table

    out = io.StringIO()
    Console(file=out, width=40).print(recording_table(None, None, "ws://127.0.0.1:40123"))
    lines = out.getvalue().splitlines()
    assert lines[0].strip() == "Foxglove ws://127.0.0.1:40123"  # first: no short panel crops it
    assert "not recording" in lines[1]


# -- both names of the protocol (bench/mcaplog/foxglove_front.py) ------------------------------
OLD, NEW = "foxglove.websocket.v1", "foxglove.sdk.v1"


def _one_step_stream(offered: tuple[str, ...]) -> tuple[Any, Any]:
    """A stream on an ephemeral port, a client offering ``offered``, a short emulated run
    through it; (what the client received, the emulated run)."""
    config = Config()
    stream = stream_sink(config, port=0)
    try:
        client = Client(stream.port, subprotocols=offered).start()
        sim = emulated(3.0, faults=False)
        step = 450
        batches = [SourceBatch(sim.frames[i : i + step]) for i in range(0, len(sim.frames), step)]
        run_pipeline(batches, config, sinks=[stream])
        stream.close()
        client.wait_quiet(quiet_s=1.0)
    finally:
        stream.close()
    return client.stop(), sim


@pytest.mark.parametrize("offered", [(OLD,), (NEW,)], ids=["websocket.v1", "sdk.v1"])
def test_a_client_offering_either_name_is_served(offered: tuple[str, ...]) -> None:
    """Issue 28: Lichtblick, older Foxglove Studio and foxglove_bridge-era tools offer only
    foxglove.websocket.v1, which the SDK alone refuses with HTTP 400."""
    got, sim = _one_step_stream(offered)
    assert not got.errors
    assert got.subprotocol == offered[0]  # the name the client asked for, back
    assert got.server_info.get("name") == "gradient bench"
    assert len(got.messages["/can/frames"]) == len(sim.frames)


def test_a_client_offering_neither_name_gets_http_400() -> None:
    import websockets

    stream = stream_sink(Config(), port=0)
    try:

        async def connect() -> None:
            async with websockets.connect(
                f"ws://127.0.0.1:{stream.port}",
                subprotocols=["some.other.v1"],  # type: ignore[list-item]
                proxy=None,
            ):
                pass

        with pytest.raises(websockets.InvalidStatus) as e:
            asyncio.run(connect())
        assert e.value.response.status_code == 400
    finally:
        stream.close()


def test_the_handshake_rewrite_by_hand() -> None:
    from bench.mcaplog.foxglove_front import rewrite_request, rewrite_response

    old_only = (
        b"GET / HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nUpgrade: websocket\r\n"
        b"sec-websocket-protocol:  foxglove.websocket.v1 \r\nSec-WebSocket-Key: abc==\r\n\r\n"
    )
    head, renamed = rewrite_request(old_only)
    assert renamed
    assert head == old_only.replace(
        b"sec-websocket-protocol:  foxglove.websocket.v1 ",
        b"Sec-WebSocket-Protocol: foxglove.sdk.v1",
    )
    both = old_only.replace(b"foxglove.websocket.v1 ", b"foxglove.websocket.v1, foxglove.sdk.v1")
    assert rewrite_request(both) == (both, False)  # the SDK's own name offered: untouched
    other = old_only.replace(b"foxglove.websocket.v1", b"x.v1")
    assert rewrite_request(other) == (other, False)  # the SDK says 400, as it should
    answer = (
        b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n"
        b"sec-websocket-accept: xyz=\r\n\r\n"
    )
    assert rewrite_response(answer) == answer.replace(
        b"sec-websocket-protocol: foxglove.sdk.v1", b"Sec-WebSocket-Protocol: foxglove.websocket.v1"
    )
