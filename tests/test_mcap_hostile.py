"""Hostile MCAP input (issue 16 items 4, 5, 12): files from other writers, one corrupt record
in the middle of a file, a malformed summary. Every test builds its damaged file itself.

Expectations are independent of the bench's reader: frame counts come from what the test
wrote, payloads are packed by hand from the documented 38-byte RawFrame layout."""

from __future__ import annotations

import logging
import struct
from pathlib import Path

import pytest
from mcap.writer import CompressionType, Writer

from bench.cli import main
from bench.config import Config
from bench.mcaplog import schemas as S
from bench.mcaplog.reader import McapLog
from bench.mcaplog.sink import McapSink
from bench.mcaplog.source import McapFrameSource
from devices.formats import open_log
from tests.test_mcap_support import run_pipeline, synthetic_stream


def raw_frame(t: float, can_id: int, data: bytes) -> bytes:
    """A /can/frames payload packed by hand from docs/MCAP.md's byte table."""
    padded = data.ljust(8, b"\0")
    return struct.pack(
        "<BdBIBIBIBBBBBB8s",
        0x09, t, 0x15, can_id, 0x1D, len(data), 0x25, 0, 0x28, 0, 0x30, 0, 0x3A, 8, padded,
    )  # fmt: skip


def foreign_file(path: Path, n: int, *, topic: str = S.FRAME_TOPIC, **writer_opts) -> None:
    """``n`` frames written by the mcap package's own Writer (not the bench's)."""
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=2048, compression=CompressionType.ZSTD, **writer_opts)
        w.start(profile="", library="someone-else")
        sid = w.register_schema(S.FRAME_SCHEMA_NAME, "protobuf", S.FRAME_SCHEMA_DATA)
        cid = w.register_channel(topic, "protobuf", sid)
        for k in range(n):
            t = 1000.0 + k / 600
            w.add_message(cid, int(t * 1e9), raw_frame(t, 0x101 + k % 3, bytes(8)), int(t * 1e9))
        w.finish()


def frames_replayed(path: Path) -> int:
    src = McapFrameSource(path)
    try:
        return sum(len(b.frames) for b in src.batches())
    finally:
        src.close()


@pytest.mark.parametrize(
    "opts",
    [
        {},  # chunked, schema/channel in the chunks and repeated in the summary
        {"repeat_channels": False, "repeat_schemas": False},  # only inside the chunks
        {"use_chunking": False},  # unchunked messages in the data section
    ],
    ids=["chunked", "defs-only-in-chunks", "unchunked"],
)
def test_other_writers_files_replay_every_frame(tmp_path: Path, opts: dict) -> None:
    path = tmp_path / "foreign.mcap"
    foreign_file(path, 900, **opts)
    assert frames_replayed(path) == 900
    with McapLog(path) as lg:
        assert lg.channel_id(S.FRAME_TOPIC) is not None
        assert lg.message_counts()[S.FRAME_TOPIC] == 900


def test_other_writers_file_through_the_cli(tmp_path: Path, capsys) -> None:
    path = tmp_path / "foreign.mcap"
    foreign_file(path, 600, repeat_channels=False, repeat_schemas=False)
    assert main(["replay", str(path), "--csv", str(tmp_path / "out.csv")]) == 0
    assert main(["log", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "/can/frames" in out and "frames:      600" in out


def test_file_without_our_topics_says_so_and_exits_2(tmp_path: Path, capsys) -> None:
    path = tmp_path / "other.mcap"
    foreign_file(path, 50, topic="/camera/points")
    assert main(["replay", str(path)]) == 2
    err = capsys.readouterr().err
    assert "/can/frames" in err and "/camera/points" in err and "Traceback" not in err
    assert main(["log", "info", str(path)]) == 2
    assert "/can/frames" in capsys.readouterr().err


# -- one corrupt record in the middle of our own file -------------------------------------
@pytest.fixture(scope="module")
def bench_file(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, int, list[tuple]]:
    """A finished bench file in many small chunks: its bytes, its frame count and, for each
    chunk, (offset, length, frames in it) read with the mcap package's own reader."""
    from mcap.reader import make_reader

    stream = synthetic_stream(seconds=4.0)
    path = tmp_path_factory.mktemp("hostile") / "full.mcap"
    sink = McapSink(path, Config(), {"source": "test"}, [], chunk_size=8192)
    run_pipeline(stream.batches, Config(), [sink])
    sink.close()
    data = path.read_bytes()
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    frame_ch = next(c.id for c in summary.channels.values() if c.topic == S.FRAME_TOPIC)
    per_chunk = []
    for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        n = 0
        if frame_ch in ci.message_index_offsets:  # MessageIndex: u16 channel, u32 len, 16 B each
            at = ci.message_index_offsets[frame_ch]
            n = struct.unpack_from("<I", data, at + 9 + 2)[0] // 16
        per_chunk.append((ci.chunk_start_offset, ci.chunk_length, n))
    total = len(stream.frames)
    assert sum(n for *_, n in per_chunk) == total
    return data, total, per_chunk


def _damage(data: bytes, offset: int, how: str) -> bytes:
    buf = bytearray(data)
    if how == "huge":
        struct.pack_into("<Q", buf, offset + 1, 1 << 40)
    elif how == "tiny":
        struct.pack_into("<Q", buf, offset + 1, 3)
    elif how == "opcode":
        buf[offset] = 0x55
    return bytes(buf)


@pytest.mark.parametrize("how", ["huge", "tiny", "opcode"])
def test_one_corrupt_chunk_header_loses_at_most_that_chunk(
    bench_file, tmp_path: Path, how: str, capsys
) -> None:
    data, total, chunks = bench_file
    frame_chunks = [c for c in chunks if c[2] > 0]
    off, _, n_lost_max = frame_chunks[len(frame_chunks) // 2]
    path = tmp_path / f"{how}.mcap"
    path.write_bytes(_damage(data, off, how))
    logging.getLogger("bench.mcaplog").setLevel(logging.ERROR)
    got = frames_replayed(path)
    assert total - n_lost_max <= got <= total
    with McapLog(path) as lg:
        problems = lg.verify()
        assert problems, "verify must find the damaged record"
        said = " ".join(lg.warnings)
        lost = total - got
        if lost:  # the loss is counted truthfully, from the summary's statistics
            assert f"{lost} frames" in said
    assert main(["log", "info", "--verify", str(path)]) == 1
    assert "all CRCs ok" not in capsys.readouterr().out


def test_malformed_statistics_record_is_a_warning_not_a_traceback(
    bench_file, tmp_path: Path, capsys
) -> None:
    """A Statistics record whose counts map claims more bytes than the record holds, with
    the summary CRC 0 (not recorded), so nothing stops the reader from parsing it."""
    data, total, _ = bench_file
    buf = bytearray(data)
    footer = len(buf) - 8 - 29
    summary_start = struct.unpack_from("<Q", buf, footer + 9)[0]
    struct.pack_into("<I", buf, footer + 25, 0)  # summary CRC: not recorded
    pos = summary_start
    while True:
        op, length = struct.unpack_from("<BQ", buf, pos)
        if op == 0x0B:
            counts_len_at = pos + 9 + 8 + 2 + 4 * 4 + 16
            struct.pack_into("<I", buf, counts_len_at, 0xFFFFFF)
            break
        pos += 9 + length
    path = tmp_path / "stats.mcap"
    path.write_bytes(bytes(buf))
    assert frames_replayed(path) == total
    assert main(["log", "info", str(path)]) == 0
    assert main(["replay", str(path)]) == 0
    assert main(["log", "export", str(path), "--candump", str(tmp_path / "x.log")]) == 0
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and "struct.error" not in captured.err
    with McapLog(path) as lg:
        assert any("statistics" in w.lower() for w in lg.warnings)


def test_open_log_of_foreign_file_uses_the_same_reader(tmp_path: Path) -> None:
    path = tmp_path / "foreign.mcap"
    foreign_file(path, 300, use_chunking=False)
    src = open_log(path)
    try:
        assert sum(len(b.frames) for b in src.batches()) == 300
    finally:
        src.close()


# -- the log file itself under attack (issue 16 items 7 and 13) ---------------------------
def test_a_second_writer_of_the_same_path_is_refused_without_truncating(tmp_path: Path) -> None:
    from bench.mcaplog.file import McapFile, check_writable

    path = tmp_path / "run.mcap"
    first = McapFile(path)
    first.flush_io()
    size = path.stat().st_size
    assert size > 8
    assert "another bench run" in check_writable(path)
    with pytest.raises(OSError, match="another bench run"):
        McapFile(path)
    assert path.stat().st_size == size  # the first run's bytes are untouched
    first.finish()
    assert check_writable(path) == ""  # the lock goes with the writer


def test_a_log_deleted_during_the_run_is_an_error_not_log_written(tmp_path: Path) -> None:
    stream = synthetic_stream(seconds=1.0, faults=False)
    path = tmp_path / "run.mcap"
    sink = McapSink(path, Config(), {"source": "test"}, [])
    run_pipeline(stream.batches[: len(stream.batches) // 2], Config(), [sink])
    path.unlink()
    sink.close()
    assert sink.error is not None and "deleted during the run" in sink.error


def test_a_log_replaced_during_the_run_is_an_error(tmp_path: Path) -> None:
    stream = synthetic_stream(seconds=1.0, faults=False)
    path = tmp_path / "run.mcap"
    sink = McapSink(path, Config(), {"source": "test"}, [])
    run_pipeline(stream.batches[:5], Config(), [sink])
    path.unlink()
    path.write_bytes(b"someone else's file")
    sink.close()
    assert sink.error is not None and "replaced" in sink.error


@pytest.mark.parametrize("extra", [[], ["-q"]])
def test_reader_warnings_are_printed_once(
    bench_file, tmp_path: Path, extra: list[str], capfd
) -> None:
    data, _, chunks = bench_file
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: chunks[len(chunks) // 2][0] + 50])
    assert main(["replay", *extra, str(path)]) == 0
    out, err = capfd.readouterr()
    assert (out + err).count("unfinished or truncated MCAP file") == 1


def test_run_into_an_unusable_mcap_path_is_one_line_before_the_run(tmp_path: Path, capfd) -> None:
    folder = tmp_path / "a-folder.mcap"
    folder.mkdir()
    code = main(["run", "--emulate", "level_run", "--duration", "1", "--mcap", str(folder)])
    _, err = capfd.readouterr()
    assert code == 2
    assert "cannot write the MCAP log" in err and "folder" in err
    assert "logging to" not in err and "FAILED" not in err and "Traceback" not in err
