"""Chunk layout of the bench's MCAP files: the replay's topics (frames, link errors, notices)
get chunks of their own, so a replay never decompresses the derived topics; files of the
earlier layout (every topic in the same chunks) still replay exactly; JSON and event
records are encoded exactly, whatever the batching."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.config import Config
from bench.mcaplog import schemas as S
from bench.mcaplog.encoder import MessageEncoder
from bench.mcaplog.file import McapFile
from bench.mcaplog.reader import McapLog
from bench.mcaplog.recorded import read_events, read_frames, read_results
from bench.mcaplog.sink import McapSink
from bench.mcaplog.source import McapFrameSource
from bench.records.events import EVENT_DTYPE, EventKind, describe, severity
from tests.test_mcap_support import csv_text, emulated, run_pipeline, synthetic_stream, uart_batches

REPLAY_TOPICS = {S.FRAME_TOPIC, S.LINK_ERROR_TOPIC, S.NOTICE_TOPIC}
FOXGLOVE_LEVEL = {"info": 2, "warning": 3, "error": 4}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory):
    """A live-run file (every fault kind, link errors, notices) in small chunks."""
    stream = synthetic_stream(seconds=3.0)
    path = tmp_path_factory.mktemp("layout") / "live.mcap"
    sink = McapSink(path, Config(), {"source": "layout"}, chunk_size=16384)
    results, _ = run_pipeline(stream.batches, Config(), [sink])
    sink.close()
    return stream, path, results


def replay_ids(lg: McapLog) -> set[int]:
    return {cid for t in REPLAY_TOPICS if (cid := lg.channel_id(t)) is not None}


def test_replay_topics_never_share_a_chunk_with_derived_topics(recorded) -> None:
    _, path, _ = recorded
    with McapLog(path) as lg:
        ids = replay_ids(lg)
        replay_chunk = []
        for c in lg.chunks:
            assert c.indexed
            assert set(c.index) <= ids or set(c.index).isdisjoint(ids)
            replay_chunk.append(set(c.index) <= ids)
        assert lg.channel_id(S.LINK_ERROR_TOPIC) in set().union(*(c.index for c in lg.chunks))
    assert any(replay_chunk) and not all(replay_chunk)


def test_frame_reader_decompresses_only_the_replay_chunks(
    recorded, monkeypatch: pytest.MonkeyPatch
) -> None:
    stream, path, _ = recorded
    seen: list[int] = []
    real = McapLog.decompress

    def spy(self: McapLog, info):  # type: ignore[no-untyped-def]
        seen.append(info.offset)
        return real(self, info)

    monkeypatch.setattr(McapLog, "decompress", spy)
    with McapLog(path) as lg:
        frames, errors, notices = lg.read_frames()
        wanted = [c.offset for c in lg.chunks if set(c.index) <= replay_ids(lg)]
    assert seen == wanted
    assert frames.tobytes() == stream.frames.tobytes()
    assert errors == stream.link_errors and notices == stream.notices


def test_a_damaged_derived_chunk_leaves_the_replay_whole(recorded, tmp_path: Path) -> None:
    stream, path, results = recorded
    data = bytearray(path.read_bytes())
    with McapLog(path) as lg:
        rid = lg.channel_id(S.RESULT_TOPIC)
        chunk = next(c for c in lg.chunks if rid in c.index)
        lost = chunk.index[rid][1] // 16  # MessageIndex entries are 16 bytes
    data[chunk.data_offset + chunk.data_len // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    source = McapFrameSource(bad)
    batches = list(source.batches())
    source.close()
    assert np.concatenate([b.frames for b in batches]).tobytes() == stream.frames.tobytes()
    assert not any(n.kind == "parse_error" for b in batches for n in b.notices)
    assert lost > 0 and len(read_results(bad)) == len(results) - lost
    with McapLog(bad) as lg:
        assert any("CRC" in p for p in lg.verify())


def test_files_of_the_mixed_chunk_layout_still_replay_exactly(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Files written before the replay topics had chunks of their own."""
    batches = uart_batches(emulated(13.0))
    path = tmp_path / "mixed.mcap"
    monkeypatch.setattr(MessageEncoder, "REPLAY_TOPICS", frozenset())  # one lane: mixed
    sink = McapSink(path, Config(), {}, chunk_size=16384)
    results, steps = run_pipeline(batches, Config(), [sink])
    sink.close()
    monkeypatch.undo()
    with McapLog(path) as lg:
        fid, rid = lg.channel_id(S.FRAME_TOPIC), lg.channel_id(S.RESULT_TOPIC)
        assert sum(fid in c.index and rid in c.index for c in lg.chunks) > 3
    received = np.concatenate([s.frames for s in steps if len(s.frames)])
    frames, errors, _ = read_frames(path)
    assert frames.tobytes() == received.tobytes()
    assert errors == [e for b in batches for e in b.link_errors] and len(errors) > 10
    again = list(McapFrameSource(path, batching="recorded").batches())
    assert [len(b.frames) for b in again] == [len(b.frames) for b in batches if len(b.frames)]
    replayed, _ = run_pipeline(list(McapFrameSource(path).batches(max_frames=700)), Config())
    assert csv_text(replayed) == csv_text(results)
    assert read_results(path).tobytes() == results.tobytes()


def test_lanes_are_closed_independently_and_in_time_order(tmp_path: Path) -> None:
    path = tmp_path / "lanes.mcap"
    mf = McapFile(path, chunk_size=1000, compression="")
    sid = mf.add_schema("x", "jsonschema", b"{}")
    a = mf.add_channel("/a", "json", sid)
    b = mf.add_channel("/b", "json", sid, lane=1)
    mf.add_messages(a, np.array([10], np.uint64), [b'"' + b"x" * 2000 + b'"'], [0])
    mf.add_messages(b, np.array([5], np.uint64), [b"{}"], [0])
    assert mf.maybe_flush() == 1  # only lane 0 reached chunk_size
    assert mf.pending_messages == 1
    mf.add_messages(a, np.array([20], np.uint64), [b"{}"], [1])
    assert mf.flush_chunk() == 2  # both lanes, the earlier one first
    mf.finish()
    with McapLog(path) as lg:
        assert [sorted(c.index) for c in lg.chunks] == [[a], [b], [a]]
        assert [(c.start_time, c.end_time) for c in lg.chunks] == [(10, 10), (5, 5), (20, 20)]
        assert lg.complete and lg.statistics is not None
        assert lg.statistics["channel_message_counts"] == {a: 2, b: 1}


def test_json_message_records_carry_length_sequence_and_times(tmp_path: Path) -> None:
    path = tmp_path / "json.mcap"
    mf = McapFile(path, compression="")
    cid = mf.add_channel("/x", "json", mf.add_schema("x", "jsonschema", b"{}"))
    payloads = [b'{"a":1}', '{"b":"\u00fc\u20ac"}'.encode(), b"{}"]
    mf.add_messages(cid, np.array([5, 7, 2**63], np.uint64), payloads, [0, -1, 2**32 + 3])
    mf.finish()
    with McapLog(path) as lg:
        content = next(lg.iter_chunks())
        recs = content.records(cid)
        assert [bytes(m) for m in content.payloads(cid)] == payloads
    assert recs["opcode"].tolist() == [5, 5, 5]
    assert recs["length"].tolist() == [2 + 4 + 8 + 8 + len(p) for p in payloads]
    assert recs["channel_id"].tolist() == [cid] * 3
    assert recs["sequence"].tolist() == [0, 0xFFFFFFFF, 3]  # wrapped to uint32
    assert recs["log_time"].tolist() == recs["publish_time"].tolist() == [5, 7, 2**63]


def every_event() -> np.ndarray:
    """Each kind with and without channel, sample and value, an unknown kind, odd times."""
    rows = []
    t = 1_700_000_000.25
    for kind in [*EventKind, 99]:
        rows.append((t, int(kind), 0, -1, 0))
        rows.append((t + 0.5, int(kind), 2, 1234, 0x101 if kind != EventKind.VOTE_FAIL else 5))
        t += 1.0
    rows += [(float("nan"), int(EventKind.GAP), 3, 7, 0), (float("inf"), 7, 0, 9, 12)]
    rows.append((t, int(EventKind.STATUS_FLAG), 1, 0, 0x81))
    rows.append((t, int(EventKind.LINK_ERROR), 0, -1, 3))
    return np.array(rows, dtype=EVENT_DTYPE)


def test_event_messages_render_every_kind(tmp_path: Path) -> None:
    events = every_event()
    path = tmp_path / "events.mcap"
    mf = McapFile(path)
    enc = MessageEncoder(mf)
    enc.write_events(events, 5 * 10**9)
    text = 'say "hi"\tüber'
    enc.write_events(events[:1], 5 * 10**9, name="operator", text=text)
    mf.finish()
    got = read_events(path)
    assert len(got) == len(events) + 1
    for ev, obj in zip(events, got[:-1], strict=True):
        kind = int(ev["kind"])
        if kind in EventKind._value2member_map_:
            assert obj["message"] == describe(ev)
            assert obj["kind_name"] == EventKind(kind).name
            assert obj["level"] == FOXGLOVE_LEVEL[severity(kind)]
        else:
            assert (obj["message"], obj["kind_name"], obj["level"]) == (f"EVENT {kind}", "99", 4)
        assert (obj["channel"], obj["n"], obj["value"]) == (ev["channel"], ev["n"], ev["value"])
        assert (obj["name"], obj["file"], obj["line"]) == ("bench", "", 0)
        assert "text" not in obj
        if np.isfinite(ev["t"]):
            assert obj["t"] == ev["t"]
            ns = obj["timestamp"]["sec"] * 10**9 + obj["timestamp"]["nsec"]
            assert ns == round(float(ev["t"]) * 1e9)
    assert got[-5]["t"] is None and got[-4]["t"] == float("inf")  # null, 1e999
    assert got[0]["level"] == 4 and got[0]["message"] == "CRC_ERROR id 0x000"  # by hand
    assert got[1]["message"] == "CRC_ERROR ch2 sample 1234 id 0x101"
    mark = got[-1]
    assert mark["message"] == f"CRC_ERROR id 0x000: {text}" and mark["text"] == text
    assert mark["name"] == "operator"


def test_event_records_do_not_depend_on_batching(tmp_path: Path) -> None:
    events = every_event()
    events = events[np.isfinite(events["t"])]  # a substituted log_time depends on the past
    out = []
    singles = [events[i : i + 1] for i in range(len(events))]
    for name, parts in (("one", [events]), ("each", singles)):
        path = tmp_path / f"{name}.mcap"
        mf = McapFile(path)
        enc = MessageEncoder(mf)
        for part in parts:
            enc.write_events(part, 5 * 10**9)
        mf.finish()
        with McapLog(path) as lg:
            out.append([bytes(m) for m in lg.payloads(S.EVENT_TOPIC)])
    assert out[0] == out[1] and len(out[0]) == len(events)
