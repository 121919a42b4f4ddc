"""open_log / open_log: every format round trips; every bad input ends in a notice or a
BenchError.

Round trips compare with what python-can's own reader returns for the file (and with the
frames written, field by field, for what the format can carry).
"""

from __future__ import annotations

import os
import signal
import struct
from collections.abc import Iterator
from pathlib import Path

import can
import numpy as np
import pytest

from bench.errors import BenchError
from bench.mcaplog.source import McapFrameSource
from devices.base import FileSource, SourceBatch
from devices.bus import frames_from_messages
from devices.files import UartCaptureSource
from devices.formats import open_log
from devices.writers import uart_bytes, write_candump, write_uart_bin, write_with_can_logger
from protocol.frames import FRAME_DTYPE
from protocol.layout import Outcome
from protocol.records import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, FLAG_UART
from protocol.uart import Deframer, encode_packet


def sample_frames(n: int = 300, special: bool = True) -> np.ndarray:
    rng = np.random.default_rng(5)
    f = np.zeros(n, dtype=FRAME_DTYPE)
    f["t"] = (1_700_000_000_000_000 + np.arange(n) * 1667) / 1e6
    f["id"] = 0x101 + np.arange(n) % 3
    f["dlc"] = 8
    f["data"] = rng.integers(0, 256, (n, 8))
    if special:
        f[1] = (f["t"][1], 0x1ABCDEF, 3, FLAG_EXTENDED, [1, 2, 3, 0, 0, 0, 0, 0])
        f[2] = (f["t"][2], 0x7FF, 0, FLAG_REMOTE, [0] * 8)
        f[3] = (f["t"][3], 0, 0, FLAG_ERROR | FLAG_EXTENDED, [0] * 8)
        f[4] = (f["t"][4], 0x123, 0, 0, [0] * 8)
    return f


def collect(src: FileSource, max_frames: int = 65536) -> tuple[np.ndarray, list[SourceBatch]]:
    batches = list(src.batches(max_frames))
    frames = [b.frames for b in batches]
    return (np.concatenate(frames) if frames else np.zeros(0, FRAME_DTYPE)), batches


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".trc", ".csv", ".log"])
def test_python_can_formats_round_trip(tmp_path: Path, suffix: str) -> None:
    f = sample_frames()
    if suffix == ".trc":  # python-can's TRC writer drops remote and error frames
        f = f[(f["flags"] & (FLAG_REMOTE | FLAG_ERROR)) == 0]
    path = tmp_path / f"r{suffix}"
    write_with_can_logger(path, f)
    src = open_log(path)
    got, batches = collect(src, max_frames=64)
    assert all(b.notices == [] for b in batches)
    assert [len(b.frames) for b in batches][:-1] == [64] * (len(batches) - 1)
    kwargs = {"relative_timestamp": False} if suffix == ".asc" else {}
    assert got.tobytes() == frames_from_messages(list(can.LogReader(path, **kwargs))).tobytes()
    for field in ("id", "dlc", "flags", "data"):
        assert np.array_equal(got[field], f[field]), field
    # ASC headers keep the start time to the millisecond only
    np.testing.assert_allclose(got["t"], f["t"], rtol=0, atol=1e-3 if suffix == ".asc" else 2e-6)
    assert src.position() == src.size_bytes() == path.stat().st_size


def test_fd_flag_survives_blf_and_log(tmp_path: Path) -> None:
    f = sample_frames(5, special=False)
    f["flags"][0] = FLAG_FD
    for suffix in (".blf", ".log"):
        write_with_can_logger(tmp_path / f"fd{suffix}", f)
        got, _ = collect(open_log(tmp_path / f"fd{suffix}"))
        assert got["flags"].tolist() == [FLAG_FD, 0, 0, 0, 0]


def test_uart_capture_round_trip(tmp_path: Path) -> None:
    f = sample_frames(500, special=False)
    f["dlc"][7] = 3
    f["data"][7, 3:] = 0
    write_uart_bin(tmp_path / "u.bin", f)
    got, batches = collect(open_log(tmp_path / "u.bin"), max_frames=128)
    assert all(b.link_errors == [] and b.notices == [] for b in batches)
    assert np.isnan(got["t"]).all()
    assert (got["flags"] == FLAG_UART).all()
    for field in ("id", "dlc", "data"):
        assert np.array_equal(got[field], f[field])


@pytest.mark.parametrize("chunk", [1, 7, 64, 1000, 1 << 20])
def test_uart_capture_with_noise_matches_one_deframer(tmp_path: Path, chunk: int) -> None:
    f = sample_frames(200, special=False)
    good = [encode_packet(int(i), bytes(d)) for i, d in zip(f["id"], f["data"], strict=True)]
    parts = []
    broken = 0
    for k, pkt in enumerate(good):
        parts.append(pkt)
        if k % 17 == 3:
            parts.append(pkt[: len(pkt) // 2] + b"\0")  # a cut packet: always a link error
            broken += 1
        if k % 41 == 5:
            parts.append(b"\x07" * 100 + b"\0")  # runaway: no delimiter within MAX_BODY
            broken += 1
    parts.append(good[0][:-5])  # unterminated at end of capture
    broken += 1
    blob = b"".join(parts)
    path = tmp_path / "n.bin"
    path.write_bytes(blob)
    src = UartCaptureSource(path, chunk_bytes=chunk)
    got, batches = collect(src)
    errors = [e for b in batches for e in b.link_errors]
    deframer = Deframer()
    ref_frames, ref_errors = deframer.feed(blob, float("nan"))
    ref_errors += deframer.flush()[1]
    assert len(got) == len(good) == len(ref_frames)
    assert np.array_equal(got["id"], f["id"]) and np.array_equal(got["data"], f["data"])
    assert len(errors) == len(ref_errors) == broken == src.link_errors
    assert [e.outcome for e in errors] == [e.outcome for e in ref_errors]
    assert all(e.outcome in (Outcome.COBS_ERROR, Outcome.LENGTH_ERROR) for e in errors)
    assert src.position() == src.size_bytes()


def test_candump_via_open_log_any_case(tmp_path: Path) -> None:
    f = sample_frames()
    write_candump(tmp_path / "C.LOG", f)
    got, _ = collect(open_log(tmp_path / "C.LOG"))
    assert got.tobytes() == f.tobytes()


# --- bad input -----------------------------------------------------------------------------


def one_line_error(excinfo: pytest.ExceptionInfo[BenchError]) -> str:
    text = str(excinfo.value)
    assert "\n" not in text and text
    return text


def test_unknown_extension(tmp_path: Path) -> None:
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(BenchError) as e:
        open_log(tmp_path / "x.txt")
    assert "unknown extension" in one_line_error(e)


def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(BenchError) as e:
        open_log(tmp_path / "nope.log")
    assert "not found" in one_line_error(e)
    (tmp_path / "d.blf").mkdir()
    with pytest.raises(BenchError) as e:
        open_log(tmp_path / "d.blf")
    assert "directory" in one_line_error(e)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root reads anything")
def test_unreadable_file(tmp_path: Path) -> None:
    path = tmp_path / "locked.asc"
    path.write_text("x")
    path.chmod(0)
    try:
        with pytest.raises(BenchError) as e:
            open_log(path)
        one_line_error(e)
    finally:
        path.chmod(0o600)


def test_one_opener_for_every_log_the_bench_registering_mcap(tmp_path: Path) -> None:
    """devices/ registers its formats, the bench adds MCAP: one unknown-extension line
    names all seven, and a .mcap goes to the bench's reader."""
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(BenchError) as e:
        open_log(tmp_path / "x.txt")
    assert one_line_error(e).endswith("(.log .asc .blf .trc .csv .bin .mcap)")
    (tmp_path / "x.mcap").write_bytes(b"\x89MCAP0\r\n")  # a magic and nothing else
    source = open_log(tmp_path / "x.mcap")
    assert isinstance(source, McapFrameSource)
    (notice,) = [n for b in source.batches() for n in b.notices]
    assert notice.kind == "truncated"


def drain(path: Path) -> list[SourceBatch] | BenchError:
    """Read a file to the end; BenchError is an accepted outcome, anything else fails."""
    try:
        return list(open_log(path).batches())
    except BenchError as exc:
        assert "\n" not in str(exc)
        return exc


@pytest.fixture
def alarm() -> Iterator[None]:
    """Fail instead of hanging if a reader loops forever."""

    def boom(*_: object) -> None:
        raise TimeoutError("reader did not finish")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(20)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


def test_truncated_blf_always_ends_in_notice_or_error(tmp_path: Path, alarm: None) -> None:
    write_with_can_logger(tmp_path / "ok.blf", sample_frames(2000), compression_level=0)
    raw = (tmp_path / "ok.blf").read_bytes()
    path = tmp_path / "cut.blf"
    for cut in [0, 1, 10, 143, 144, 150, 200, len(raw) // 3, len(raw) // 2, len(raw) - 1]:
        path.write_bytes(raw[:cut])
        result = drain(path)
        if isinstance(result, BenchError):
            continue
        notices = [n for b in result for n in b.notices]
        assert [n.kind for n in notices] in (["truncated"], ["parse_error"]), cut


def test_blf_with_zero_size_object_does_not_hang(tmp_path: Path, alarm: None) -> None:
    write_with_can_logger(tmp_path / "z.blf", sample_frames(50), compression_level=0)
    raw = bytearray((tmp_path / "z.blf").read_bytes())
    objects = [i for i in range(len(raw) - 4) if raw[i : i + 4] == b"LOBJ"]
    inner = objects[3]  # [0] is the container, then CAN message objects
    raw[inner + 8 : inner + 12] = (0).to_bytes(4, "little")  # obj_size = 0
    raw[inner + 12 : inner + 16] = (99).to_bytes(4, "little")  # an unknown object type
    (tmp_path / "z0.blf").write_bytes(bytes(raw))
    result = drain(tmp_path / "z0.blf")
    assert not isinstance(result, BenchError)
    assert [n.kind for b in result for n in b.notices] == ["truncated"]


CONTAINER = 8192  # uncompressed bytes of a BLF log container (python-can's max_container_size)


def blf_containers(raw: bytes) -> list[tuple[int, int]]:
    """(start, end) of each LOG_CONTAINER object of a BLF file, walking its object headers
    (LOBJ, header size, version, object size, type 10) from the file header's end."""
    off, out = struct.unpack_from("<I", raw, 4)[0], []
    while off + 16 <= len(raw):
        sig, _, _, size, kind = struct.unpack_from("<4sHHII", raw, off)
        assert sig == b"LOBJ" and kind == 10, (off, sig, kind)
        out.append((off, off + size))
        off += size + size % 4  # objects are padded to 4 bytes
    return out


def test_corrupt_compressed_blf_reads_the_containers_before_the_damage(
    tmp_path: Path, alarm: None
) -> None:
    """40 random bytes in a zlib container: every frame wholly in the containers before it is
    read, in order, and the stop is one 'truncated' notice with that count."""
    frames = sample_frames(3000)
    write_with_can_logger(tmp_path / "c.blf", frames, max_container_size=CONTAINER)
    raw = (tmp_path / "c.blf").read_bytes()
    containers = blf_containers(raw)
    assert len(containers) == 18  # 2999 CAN_MESSAGE objects of 48 bytes, one error of 64
    sizes = np.where(frames["flags"] & FLAG_ERROR, 64, 48)  # object header 32 + body
    ends = np.cumsum(sizes)
    rng = np.random.default_rng(1)
    for at in rng.integers(200, len(raw) - 40, 6).tolist():
        bad = bytearray(raw)
        bad[at : at + 40] = rng.integers(0, 256, 40, dtype=np.uint8).tobytes()
        (tmp_path / "bad.blf").write_bytes(bytes(bad))
        whole = sum(end <= at for _, end in containers)  # containers before the damage
        want = int(np.sum(ends <= whole * CONTAINER))
        result = drain(tmp_path / "bad.blf")
        assert not isinstance(result, BenchError), result
        got = np.concatenate([b.frames for b in result])
        assert got.tobytes() == frames[:want].tobytes(), (at, len(got), want)
        notices = [n for b in result for n in b.notices]
        assert [n.kind for n in notices] == ["truncated"], notices
        assert f"after {want} frames" in notices[0].detail, notices[0].detail


@pytest.mark.parametrize("suffix", [".asc", ".trc", ".csv", ".blf", ".log", ".bin", ".mcap"])
@pytest.mark.parametrize(
    "content", [b"", b"hello world\nnot a log\n", b"\x00\x01\xff\xfe" * 300, b"\n\n\n"]
)
def test_garbage_files_end_in_notice_or_bench_error(
    tmp_path: Path, suffix: str, content: bytes, alarm: None
) -> None:
    path = tmp_path / f"g{suffix}"
    path.write_bytes(content)
    result = drain(path)
    if isinstance(result, BenchError) or not content.strip(b"\n"):
        return
    notices = [n for b in result for n in b.notices]
    errors = [e for b in result for e in b.link_errors]
    assert notices or errors, "garbage must be reported"
    assert sum(len(b.frames) for b in result) == 0 or suffix == ".bin"


def test_garbage_asc_lines_among_frames(tmp_path: Path) -> None:
    write_with_can_logger(tmp_path / "a.asc", sample_frames(20, special=False))
    text = (tmp_path / "a.asc").read_text().splitlines()
    text.insert(6, "complete nonsense 1 2 3")
    (tmp_path / "b.asc").write_text("\n".join(text) + "\n")
    result = drain(tmp_path / "b.asc")
    assert not isinstance(result, BenchError)  # python-can skips lines it does not know
    assert sum(len(b.frames) for b in result) == 20


def test_uart_bytes_helper_matches_file(tmp_path: Path) -> None:
    f = sample_frames(10, special=False)
    write_uart_bin(tmp_path / "h.bin", f)
    assert (tmp_path / "h.bin").read_bytes() == uart_bytes(f)
