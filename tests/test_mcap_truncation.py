"""A truncated or damaged MCAP file: every complete chunk is recovered, the loss is reported,
nothing raises, and the CLI still exits 0."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.config import Config
from bench.mcaplog.reader import McapLog
from bench.mcaplog.recorded import read_frames
from bench.mcaplog.sink import McapSink
from bench.mcaplog.source import McapFrameSource
from bench.mcaplog.structure import McapReadError
from tests.test_mcap_support import run_pipeline, synthetic_stream


@pytest.fixture(scope="module")
def small_chunks(tmp_path_factory: pytest.TempPathFactory):
    """A complete live-run file cut into many small chunks, with its frames per chunk."""
    stream = synthetic_stream(seconds=3.0)
    path = tmp_path_factory.mktemp("trunc") / "full.mcap"
    sink = McapSink(path, Config(), {"source": "test"}, [("cal.toml", b"x = 1\n")], chunk_size=8192)
    run_pipeline(stream.batches, Config(), [sink])
    sink.close()
    with McapLog(path) as lg:
        assert lg.complete and len(lg.chunks) > 10
        ends = [c.end for c in lg.chunks]
        per_chunk = [len(lg.frame_records(c)) for c in lg.iter_chunks()]
        data_end = lg.scan_end  # just past the DataEnd record
    return stream, path, path.read_bytes(), np.array(ends), np.cumsum(per_chunk), data_end


def expected_frames(ends: np.ndarray, cum: np.ndarray, cut: int) -> int:
    """Frames in the chunks that lie wholly before ``cut``."""
    k = int(np.searchsorted(ends, cut, side="right"))
    return int(cum[k - 1]) if k else 0


def cut_offsets(data: bytes, ends: np.ndarray, n_random: int = 60) -> list[int]:
    rng = np.random.default_rng(2024)
    edges = {0, 1, 7, 8, 9, 20, len(data) - 1, len(data) - 8, len(data) - 30}
    for e in ends[:6].tolist() + ends[-3:].tolist():
        edges |= {e - 1, e, e + 1, e + 9, e + 40}
    return sorted(edges | set(rng.integers(0, len(data), n_random).tolist()))


def test_every_cut_recovers_all_complete_chunks(small_chunks, tmp_path: Path) -> None:
    stream, _, data, ends, cum, data_end = small_chunks
    logging.getLogger("bench.mcaplog").setLevel(logging.ERROR)  # hundreds of expected warnings
    try:
        for cut in cut_offsets(data, ends):
            path = tmp_path / f"cut{cut}.mcap"
            path.write_bytes(data[:cut])
            if cut < 8:  # not even the magic: an empty recording, still no exception
                with McapLog(path) as lg:
                    assert lg.truncated and lg.read_frames()[0].size == 0
                continue
            source = McapFrameSource(path)
            batches = list(source.batches(max_frames=1000))
            source.close()
            frames = np.concatenate(
                [b.frames for b in batches if len(b.frames)] or [stream.frames[:0]]
            )
            want = expected_frames(ends, cum, cut)
            assert len(frames) == want, f"cut at {cut}"
            assert frames.tobytes() == stream.frames[:want].tobytes()
            notices = [n for b in batches for n in b.notices if n.kind == "truncated"]
            if cut < data_end:
                assert len(notices) == 1 and "lost about" in notices[0].detail, f"cut at {cut}"
            else:  # the data section is whole; only the summary (an index) is cut
                assert notices == [], f"cut at {cut}"
            path.unlink()
    finally:
        logging.getLogger("bench.mcaplog").setLevel(logging.NOTSET)


def test_truncated_file_warns_with_the_loss(small_chunks, tmp_path: Path, caplog) -> None:
    _, full, data, ends, _, _ = small_chunks
    with McapLog(full) as lg:
        seventh = lg.chunks[6]
    cut = seventh.offset + 100  # inside chunk 7's record
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[:cut])
    with caplog.at_level(logging.WARNING, logger="bench.mcaplog"), McapLog(path) as lg:
        assert lg.truncated and not lg.complete
        assert len(lg.chunks) == 6 and lg.lost_bytes == 100
        assert "Chunk record" in lg.truncation and "lost about 100 bytes" in lg.truncation
        assert "the last chunk, cut short" in lg.truncation
        assert lg.metadata_dict()["run"]["source"] == "test"  # the start of the file survives
        assert [a.name for a in lg.attachments] == ["cal.toml"]
    assert any("lost about" in r.getMessage() for r in caplog.records)
    path.write_bytes(data[: int(ends[5]) + 100])  # inside chunk 6's MessageIndex
    with McapLog(path) as lg:
        assert len(lg.chunks) == 6 and "no messages lost" in lg.truncation


def test_chunk_whose_message_index_was_cut_is_walked(small_chunks, tmp_path: Path) -> None:
    stream, _, data, ends, cum, _ = small_chunks
    path = tmp_path / "noindex.mcap"
    path.write_bytes(data[: int(ends[3]) + 12])  # chunk 4 whole, its MessageIndex cut
    with McapLog(path) as lg:
        assert len(lg.chunks) == 4 and not lg.chunks[3].indexed and lg.chunks[2].indexed
        frames, _, _ = lg.read_frames()
    assert frames.tobytes() == stream.frames[: int(cum[3])].tobytes()


def test_corrupt_chunk_is_skipped_with_a_notice(small_chunks, tmp_path: Path) -> None:
    stream, _, data, _, cum, _ = small_chunks
    bad = bytearray(data)
    with McapLog(small_chunks[1]) as lg:
        k = int(np.flatnonzero(np.diff(cum, prepend=0))[1])  # the second chunk with frames
        c = lg.chunks[k]
    bad[c.data_offset + c.data_len // 2] ^= 0xFF
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(bad))
    source = McapFrameSource(path)
    batches = list(source.batches())
    frames = np.concatenate([b.frames for b in batches if len(b.frames)])
    assert len(frames) == len(stream.frames) - (int(cum[k]) - int(cum[k - 1]))
    assert any(
        n.kind == "parse_error" and "skipped" in n.detail for b in batches for n in b.notices
    )
    with McapLog(path) as lg:
        assert lg.verify()  # the CRC problem is reported


def test_cli_replay_and_info_of_a_truncated_file_exit_0(
    small_chunks, tmp_path: Path, capsys
) -> None:
    _, _, data, ends, _, _ = small_chunks
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: int(ends[-2]) + 333])
    out = tmp_path / "out.csv"
    assert main(["replay", str(path), "--csv", str(out), "--quiet"]) == 0
    assert out.read_text().count("\n") > 100
    captured = capsys.readouterr()
    assert "lost about" in captured.out + captured.err
    assert main(["log", "info", str(path)]) == 0
    captured = capsys.readouterr()
    assert "UNFINISHED" in captured.out and "lost about" in captured.err


def test_not_an_mcap_file_is_a_bench_error(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(b"hello world, not mcap")
    with pytest.raises(McapReadError):
        read_frames(path)
    assert main(["log", "info", str(path)]) == 2
