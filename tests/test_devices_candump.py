"""The fast candump reader against python-can's own CanutilsLogReader.

Files are written by python-can's CanutilsLogWriter from python-can Messages built here
(not through the bench's writers), so the expectation is python-can's round trip: our
frames must equal python-can's reader's frames bit for bit (timestamps included), and a
line python-can cannot read must be exactly one parse_error notice naming its line.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from devices import candump
from devices.bus import frames_from_messages
from devices.candump import CandumpFileSource, parse_candump_bytes, read_candump
from protocol.frames import FRAME_DTYPE
from protocol.records import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE

FD_LENGTHS = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]
SETTINGS = settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

timestamps = st.one_of(
    st.integers(0, 4_000_000_000 * 10**6).map(lambda us: us / 1e6),  # bench convention
    st.floats(0, 4e9, allow_nan=False),
    st.floats(0, 2, allow_nan=False),
)


@st.composite
def messages(draw: st.DrawFn) -> can.Message:
    kind = draw(st.sampled_from(["std", "ext", "remote", "error", "fd"]))
    t = draw(timestamps)
    channel = draw(st.sampled_from([None, 0, 1, "can0", "vcan1", "slcan_0"]))
    is_rx = draw(st.booleans())
    ext = kind == "ext" or (kind in ("remote", "fd") and draw(st.booleans()))
    can_id = draw(st.integers(0, 0x1FFFFFFF if ext else 0x7FF))
    if kind == "error":
        return can.Message(timestamp=t, is_error_frame=True, data=draw(st.binary(max_size=8)))
    if kind == "remote":
        return can.Message(
            timestamp=t, arbitration_id=can_id, is_extended_id=ext, is_remote_frame=True,
            channel=channel, is_rx=is_rx,
        )  # fmt: skip
    if kind == "fd":
        n = draw(st.sampled_from(FD_LENGTHS))
        return can.Message(
            timestamp=t, arbitration_id=can_id, is_extended_id=ext, is_fd=True,
            bitrate_switch=draw(st.booleans()), error_state_indicator=draw(st.booleans()),
            data=draw(st.binary(min_size=n, max_size=n)), channel=channel, is_rx=is_rx,
        )  # fmt: skip
    return can.Message(
        timestamp=t, arbitration_id=can_id, is_extended_id=ext,
        data=draw(st.binary(max_size=8)), channel=channel, is_rx=is_rx,
    )  # fmt: skip


def python_can_write(path: Path, msgs: list[can.Message]) -> None:
    writer = can.CanutilsLogWriter(path)
    for msg in msgs:
        writer.on_message_received(msg)
    writer.stop()


def python_can_read(path: Path) -> np.ndarray:
    return frames_from_messages(list(can.CanutilsLogReader(path)))


def python_can_line(line: bytes) -> tuple[list[can.Message], bool]:
    """python-can's reading of one physical line, as it would see it in a file
    (universal newlines): the messages it yields and whether it then raises."""
    text = io.TextIOWrapper(io.BytesIO(line + b"\n"), encoding="utf-8", newline=None)
    out: list[can.Message] = []
    try:
        for msg in can.CanutilsLogReader(text):
            out.append(msg)
    except Exception:
        return out, True
    return out, False


def notice_lines(notices: list) -> list[int]:
    return [int(re.match(r"line (\d+): ", n.detail).group(1)) for n in notices]


@SETTINGS
@given(msgs=st.lists(messages(), min_size=1, max_size=40))
def test_equals_python_can_on_python_can_files(tmp_path: Path, msgs: list[can.Message]) -> None:
    path = tmp_path / "x.log"
    python_can_write(path, msgs)
    ours, notices = read_candump(path)
    expected = python_can_read(path)
    assert notices == []
    assert ours.dtype == FRAME_DTYPE
    assert ours.tobytes() == expected.tobytes()  # bitwise: t == float(text) included


def test_hand_written_lines_decode_to_known_values(tmp_path: Path) -> None:
    path = tmp_path / "hand.log"
    path.write_text(
        "(1700000000.123456) can0 101#0102030405060708 R\n"
        "(0.000001) vcan0 1ABCDEF0#AA T\n"
        "(2.5) can0 7FF#R\n"
        "(3.000000) can0 20000080#0102\n"
        "(4.000000) can0 123##3" + "11" * 12 + "\n"
        "(5.000000) can0 456#\n"
    )
    f, notices = read_candump(path)
    assert notices == []
    assert f["t"].tolist() == [1700000000.123456, 0.000001, 2.5, 3.0, 4.0, 5.0]
    assert f["id"].tolist() == [0x101, 0x1ABCDEF0 & 0x1FFFFFFF, 0x7FF, 0, 0x123, 0x456]
    assert f["dlc"].tolist() == [8, 1, 0, 0, 12, 0]
    assert f["flags"].tolist() == [
        0,
        FLAG_EXTENDED,
        FLAG_REMOTE,
        FLAG_ERROR | FLAG_EXTENDED,  # python-can: a default Message, extended id 0
        FLAG_FD,
        0,
    ]
    assert f["data"][0].tolist() == [1, 2, 3, 4, 5, 6, 7, 8]
    assert f["data"][1].tolist() == [0xAA, 0, 0, 0, 0, 0, 0, 0]
    assert f["data"][4].tolist() == [0x11] * 8


MUTATION_ALPHABET = "0123456789abcdefABCDEFxX#RrTt.()+-_ \t\r\x00\xe9\u00a0"


@st.composite
def mutated_line(draw: st.DrawFn) -> str:
    buf = io.StringIO()
    writer = can.CanutilsLogWriter(buf)
    writer.on_message_received(draw(messages()))
    line = list(buf.getvalue().rstrip("\n"))
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["replace", "insert", "delete"]))
        pos = draw(st.integers(0, max(0, len(line) - 1)))
        char = draw(st.sampled_from(MUTATION_ALPHABET))
        if op == "replace" and line:
            line[pos] = char
        elif op == "insert":
            line.insert(pos, char)
        elif line:
            del line[pos]
    return "".join(line)


any_line = st.one_of(
    mutated_line(),
    st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\n"), max_size=40),
    st.sampled_from(
        [
            "",
            "   ",
            "(1.5) can0 123#R5",
            "(1.5) can0 123##1R",
            "(1.5) can0 0x123#0102",
            "(1.5) can0 123#+1",
            "(1.5) can0 123#ABC",
            "(1.5)  can0 123#AB",
            " (1.5) can0 123#AB R ",
            "(1.5)\tcan0\t123#AB",
            "(1e3) can0 123#AB",
            "(inf) can0 123#AB",
            "(1.5) can0 123#AB X",
            "(1.5) can0 #AB",
            "(12345678901234567.5) can0 123#AB",
            "(1.5) can0 123456789#AB",
            "(1.5) can0 123#AB\r(2.5) can0 124#CD",
            "(1.5) can0 123#AB\rgarbage",
            "garbage",
        ]
    ),
)


@SETTINGS
@given(lines=st.lists(any_line, min_size=1, max_size=30))
def test_any_line_matches_python_can_or_is_one_notice(tmp_path: Path, lines: list[str]) -> None:
    raw_lines = [line.encode("utf-8") for line in lines]
    path = tmp_path / "mixed.log"
    path.write_bytes(b"\n".join(raw_lines) + b"\n")
    expected_msgs: list[can.Message] = []
    expected_errors = []
    for number, raw in enumerate(raw_lines, start=1):
        msgs, failed = python_can_line(raw)
        expected_msgs += msgs
        if failed:
            expected_errors.append(number)
    ours, notices = read_candump(path)
    assert ours.tobytes() == frames_from_messages(expected_msgs).tobytes()
    assert notice_lines(notices) == expected_errors
    assert all(n.kind == "parse_error" for n in notices)


def test_garbage_lines_are_counted_and_never_fatal(tmp_path: Path) -> None:
    path = tmp_path / "g.log"
    path.write_bytes(
        b"(1.000000) can0 101#01 R\n"
        b"this is not a frame\n"
        b"\xff\xfe\x00binary\n"
        b"(2.000000) can0 102#ZZ R\n"
        b"\n"
        b"(3.000000) can0 103#03 R\n"
    )
    src = CandumpFileSource(path)
    batches = list(src.batches())
    frames = np.concatenate([b.frames for b in batches])
    notices = [n for b in batches for n in b.notices]
    assert frames["id"].tolist() == [0x101, 0x103]
    assert notice_lines(notices) == [2, 3, 4]
    assert src.parse_errors == 3 and src.frames == 2 and src.lines == 6
    assert all("\n" not in n.detail for n in notices)


def test_crlf_file_reads_like_lf(tmp_path: Path) -> None:
    lf = b"(1.000000) can0 101#01 R\n(2.000000) can0 102#0203 T\n"
    (tmp_path / "lf.log").write_bytes(lf)
    (tmp_path / "crlf.log").write_bytes(lf.replace(b"\n", b"\r\n"))
    a, na = read_candump(tmp_path / "lf.log")
    b, nb = read_candump(tmp_path / "crlf.log")
    assert na == nb == [] and a.tobytes() == b.tobytes() and len(a) == 2


def test_small_chunks_give_the_same_result(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    lines = []
    for k in range(3000):
        if k % 97 == 5:
            lines.append(f"junk line {k}")
        else:
            data = rng.integers(0, 256, int(rng.integers(0, 9)), dtype=np.uint8).tobytes()
            lines.append(f"({k * 0.001234:f}) can0 {0x100 + k % 7:03X}#{data.hex().upper()} R")
    path = tmp_path / "c.log"
    path.write_text("\n".join(lines) + "\n")
    whole, n_whole = read_candump(path)
    src = CandumpFileSource(path, chunk_bytes=1024)
    parts = list(src.batches(max_frames=100))
    assert all(len(p.frames) <= 100 for p in parts)
    chunked = np.concatenate([p.frames for p in parts])
    n_chunked = [n for p in parts for n in p.notices]
    assert chunked.tobytes() == whole.tobytes()
    assert n_chunked == n_whole
    assert notice_lines(n_whole) == [k + 1 for k in range(3000) if k % 97 == 5]
    assert src.position() == src.size_bytes() == path.stat().st_size
    assert whole.tobytes() == python_can_read_lines(lines).tobytes()


def python_can_read_lines(lines: list[str]) -> np.ndarray:
    msgs = []
    for line in lines:
        got, _ = python_can_line(line.encode())
        msgs += got
    return frames_from_messages(msgs)


def test_notices_ride_with_the_batch_of_their_line(tmp_path: Path) -> None:
    lines = [f"({k}.000000) can0 101#01 R" for k in range(10)]
    lines.insert(7, "bad")
    path = tmp_path / "n.log"
    path.write_text("\n".join(lines) + "\n")
    batches = list(CandumpFileSource(path).batches(max_frames=3))
    assert [len(b.frames) for b in batches] == [3, 3, 3, 1]
    assert [len(b.notices) for b in batches] == [0, 0, 1, 0]  # after frame 7 -> 3rd batch


def test_overlong_line_is_one_notice(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(candump, "MAX_LINE_BYTES", 3000)
    path = tmp_path / "long.log"
    path.write_bytes(
        b"(1.000000) can0 101#01 R\n" + b"x" * 10_000 + b"\n(2.000000) can0 102#02 R\n"
    )
    src = CandumpFileSource(path, chunk_bytes=1024)
    batches = list(src.batches())
    frames = np.concatenate([b.frames for b in batches])
    notices = [n for b in batches for n in b.notices]
    assert frames["id"].tolist() == [0x101, 0x102]
    assert notice_lines(notices) == [2]
    assert src.lines == 3


def test_random_binary_never_raises(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    blob = rng.integers(0, 256, 50_000, dtype=np.uint8).tobytes()
    path = tmp_path / "bin.log"
    path.write_bytes(blob + b"\n(9.000000) can0 109#09 R\n")
    frames, notices = read_candump(path)
    assert frames["id"].tolist()[-1] == 0x109
    assert len(notices) >= 1 and all(n.kind == "parse_error" for n in notices)


def test_empty_and_blank_files(tmp_path: Path) -> None:
    (tmp_path / "e.log").write_bytes(b"")
    (tmp_path / "b.log").write_bytes(b"\n\n  \n")
    for name in ("e.log", "b.log"):
        frames, notices = read_candump(tmp_path / name)
        assert len(frames) == 0 and notices == []


def test_parse_bytes_without_trailing_newline() -> None:
    chunk = parse_candump_bytes(b"(1.000000) can0 101#01 R\n(2.000000) can0 102#02", 10)
    assert chunk.frames["id"].tolist() == [0x101, 0x102]
    assert chunk.n_lines == 2
