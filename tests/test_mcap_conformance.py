"""Our MCAP files read by @mcap/core, the reader Foxglove uses (tests/js/check_mcap.mjs):
channels, schemas, message counts (index, stream and Statistics agree), every CRC, and
every message decoded the way Foxglove decodes it (protobufjs / JSON + jsonschema).

The npm packages are installed by the ``mcap_js`` fixture (tests/mcap_js.py); under CI
a missing node/npm fails these tests instead of skipping them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from bench.config import Config
from bench.mcaplog import schemas as S
from bench.mcaplog.emulation import write_emulation
from bench.mcaplog.encoder import MessageEncoder
from bench.mcaplog.file import McapFile
from bench.mcaplog.reader import McapLog
from bench.mcaplog.sink import McapSink
from tests.mcap_js import McapJs, install
from tests.test_mcap_support import emulated, run_pipeline, synthetic_stream, uart_batches

ALL_TOPICS = {spec.topic for spec in S.TOPICS}


@pytest.fixture(scope="session")
def mcap_js() -> McapJs:
    return install()


@pytest.fixture(scope="module")
def live_file(tmp_path_factory: pytest.TempPathFactory):
    """A live-run file with every topic populated (faults, link errors, notices, a mark)."""
    stream = synthetic_stream(seconds=3.0)
    cfg = Config()
    path = tmp_path_factory.mktemp("js") / "live.mcap"
    sink = McapSink(path, cfg, {"source": "conformance"}, [("cal.toml", cfg.to_toml().encode())])
    results, steps = run_pipeline(stream.batches, cfg, [sink])
    sink.mark(float(stream.frames["t"][-1]), "mark for Foxglove")
    sink.close()
    expected = {
        S.FRAME_TOPIC: len(stream.frames),
        S.LINK_ERROR_TOPIC: len(stream.link_errors),
        S.NOTICE_TOPIC: len(stream.notices),
        S.SAMPLE_TOPIC: sum(len(s.samples) for s in steps),
        S.RESULT_TOPIC: len(results),
        S.STATUS_TOPIC: sum(len(s.status) for s in steps),
        S.SPEED_TOPIC: sum(len(s.speed) for s in steps),
        S.EVENT_TOPIC: sum(len(s.events) for s in steps) + 1,
    }
    return path, stream, results, expected


def test_live_file_conforms(mcap_js: McapJs, live_file) -> None:
    path, stream, results, expected = live_file
    report = mcap_js.check(path)
    channels = {c["topic"]: c for c in report["channels"]}
    assert set(channels) == ALL_TOPICS
    for topic, count in expected.items():
        assert channels[topic]["count"] == count, topic
    assert channels[S.HEALTH_TOPIC]["count"] >= 3
    assert report["statistics"]["messageCount"] == sum(c["count"] for c in channels.values())
    assert report["dataSectionCrc"] == "ok"
    assert report["stream"]["done"] is True
    assert report["compression"] == ["zstd"]

    frames = channels[S.FRAME_TOPIC]
    assert (frames["messageEncoding"], frames["schemaEncoding"]) == ("protobuf", "protobuf")
    assert frames["schemaName"] == "acb3.bench.RawFrame"
    first = frames["first"]["value"]
    f0 = stream.frames[0]
    assert first["t"] == float(f0["t"]) and first["id"] == int(f0["id"])
    assert first["dlc"] == 8 and first["data"] == f0["data"].tolist() and first["outcome"] == "OK"
    assert frames["first"]["sequence"] == int(f0["data"][0])  # the frame counter

    for topic in ALL_TOPICS - {S.FRAME_TOPIC}:
        assert (channels[topic]["messageEncoding"], channels[topic]["schemaEncoding"]) == (
            "json",
            "jsonschema",
        ), topic
    assert channels[S.EVENT_TOPIC]["schemaName"] == "foxglove.Log"
    res = channels[S.RESULT_TOPIC]["first"]["value"]
    r0 = results[0]
    assert res["n"] == int(r0["n"]) and res["time_s"] == float(r0["time_s"])
    for name, k in (("a1", 0), ("a2", 1), ("a3", 2)):
        v = float(r0["acc"][k])
        assert (res[name] is None) if math.isnan(v) else res[name] == v  # exact in JS too
    link = channels[S.LINK_ERROR_TOPIC]["first"]["value"]
    assert link["outcome_name"] == stream.link_errors[0].outcome.name
    assert {m["name"] for m in report["metadata"]} == {"run", "config", "summary"}
    assert report["attachments"] == [
        {"name": "cal.toml", "mediaType": "application/toml", "size": len(Config().to_toml())}
    ]


def test_emulator_file_conforms(mcap_js: McapJs, tmp_path: Path) -> None:
    sim = emulated(13.0)
    scenario = tmp_path / "scenario.toml"
    scenario.write_text('description = "conformance"\n')
    path = tmp_path / "emu.mcap"
    write_emulation(path, [sim], sim.scenario, scenario)
    report = mcap_js.check(path)
    channels = {c["topic"]: c for c in report["channels"]}
    assert set(channels) == ALL_TOPICS | {S.TRUTH_TOPIC}
    assert channels[S.FRAME_TOPIC]["count"] == len(sim.frames)
    assert channels[S.TRUTH_TOPIC]["count"] == len(sim.truth)
    truth = channels[S.TRUTH_TOPIC]["first"]["value"]
    assert set(truth) == set(sim.truth.dtype.names)
    assert report["attachments"][0]["name"] == "scenario.toml"


@pytest.mark.parametrize("compression", ["lz4", ""])
def test_other_compressions_conform(mcap_js: McapJs, tmp_path: Path, compression: str) -> None:
    frames = synthetic_stream(seconds=1.0).frames
    path = tmp_path / f"c{compression or 'none'}.mcap"
    mf = McapFile(path, compression=compression, chunk_size=4096)
    enc = MessageEncoder(mf)
    for i in range(0, len(frames), 50):
        enc.write_frames(frames[i : i + 50], None, 0)
        mf.maybe_flush()
    mf.finish()
    report = mcap_js.check(path)
    assert report["chunkCount"] > 5
    assert {c["topic"]: c["count"] for c in report["channels"]}[S.FRAME_TOPIC] == len(frames)
    with McapLog(path) as lg:
        assert lg.read_frames()[0].tobytes() == frames.tobytes()


def test_unfinished_file_streams_in_mcap_core(mcap_js: McapJs, tmp_path: Path) -> None:
    """Foxglove opens an unfinished file by streaming it: the complete chunks read."""
    batches = uart_batches(emulated(13.0))
    path = tmp_path / "live.mcap"
    sink = McapSink(path, Config(), {}, chunk_size=16384)
    run_pipeline(batches, Config(), [sink])
    sink.close()
    data = path.read_bytes()
    with McapLog(path) as lg:
        cut = lg.chunks[len(lg.chunks) // 2].end + 50
    (tmp_path / "cut.mcap").write_bytes(data[:cut])
    report = mcap_js.check(tmp_path / "cut.mcap", stream_only=True)
    assert report["stream"]["done"] is False
    with McapLog(tmp_path / "cut.mcap") as lg:
        ours = lg.message_counts()
    assert report["stream"]["counts"] == ours
    assert 0 < ours[S.FRAME_TOPIC] < sum(len(b.frames) for b in batches)


def test_checker_catches_a_bad_crc(mcap_js: McapJs, live_file, tmp_path: Path) -> None:
    """The checker really checks: a flipped byte inside a chunk fails it."""
    path = live_file[0]
    with McapLog(path) as lg:
        c = lg.chunks[0]
    data = bytearray(path.read_bytes())
    data[c.data_offset + c.data_len // 3] ^= 0x55
    (tmp_path / "bad.mcap").write_bytes(bytes(data))
    report = mcap_js.check(tmp_path / "bad.mcap", expect_ok=False)
    assert report["errors"]


def test_frame_payload_is_plain_protobuf_wire_format() -> None:
    """Independent of protobufjs: walk the payload as protobuf wire format by hand."""
    frames = synthetic_stream(seconds=0.1, faults=False).frames[:5]
    enc = MessageEncoder.__new__(MessageEncoder)
    enc.base_id, enc.cid, enc.last_ns, enc.substituted = 0x100, {S.FRAME_TOPIC: 1}, 0, 0
    recs = enc.frames_records(frames, np.zeros(5, np.uint8), 0)
    payload = recs["payload"][0].tobytes()
    fields: dict[int, object] = {}
    i = 0
    while i < len(payload):
        key = payload[i]
        i += 1
        num, wire = key >> 3, key & 7
        if wire == 1:
            fields[num] = np.frombuffer(payload[i : i + 8], "<f8")[0]
            i += 8
        elif wire == 5:
            fields[num] = int.from_bytes(payload[i : i + 4], "little")
            i += 4
        elif wire == 0:
            fields[num] = payload[i]
            assert payload[i] < 0x80  # one-byte varint
            i += 1
        else:
            assert wire == 2
            n = payload[i]
            fields[num] = payload[i + 1 : i + 1 + n]
            i += 1 + n
    assert fields == {
        1: frames["t"][0],
        2: int(frames["id"][0]),
        3: 8,
        4: 0,
        5: 0,
        6: 0,
        7: frames["data"][0].tobytes(),
    }
