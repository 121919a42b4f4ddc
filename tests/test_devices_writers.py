"""The vectorised candump writer is byte-identical to python-can's CanutilsLogWriter.

The expectation is python-can's own writer fed the same frames as Messages; timestamps are
drawn to hit its rounding corners (exact half-microsecond ties such as k/128 s, values just
beside them, NaN, negative zero, huge and tiny values).
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.errors import BenchError
from devices.bus import messages_from_frames
from devices.candump import read_candump
from devices.writers import CandumpWriter, format_candump, uart_bytes, write_candump
from protocol.frames import FRAME_DTYPE
from protocol.uart import encode_packet

SETTINGS = settings(
    max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

tie_times = st.integers(0, 2**40).map(lambda k: k / 128)  # x.0078125: exact ties at 1 us
near_times = st.integers(0, 2**40).map(lambda k: math.nextafter(k / 128, math.inf))
special = st.sampled_from([0.0, -0.0, 0.5e-6, 1.5e-6, 2.5e-6, -1.25, 1e13, math.inf, math.nan])
times = st.one_of(
    st.floats(0, 4e9, allow_nan=False),
    st.integers(0, 4 * 10**15).map(lambda us: us / 1e6),
    tie_times,
    near_times,
    special,
)


@st.composite
def frame_arrays(draw: st.DrawFn) -> np.ndarray:
    n = draw(st.integers(1, 40))
    f = np.zeros(n, dtype=FRAME_DTYPE)
    f["t"] = draw(st.lists(times, min_size=n, max_size=n))
    f["flags"] = draw(st.lists(st.integers(0, 15), min_size=n, max_size=n))
    f["id"] = draw(st.lists(st.integers(0, 2**32 - 1), min_size=n, max_size=n))
    f["dlc"] = draw(st.lists(st.integers(0, 15), min_size=n, max_size=n))
    f["data"] = np.frombuffer(draw(st.binary(min_size=8 * n, max_size=8 * n)), np.uint8).reshape(
        n, 8
    )
    return f


def python_can_text(frames: np.ndarray, channel: object = "can0") -> bytes:
    buf = io.StringIO()
    writer = can.CanutilsLogWriter(buf, channel=channel)
    for msg in messages_from_frames(frames):
        writer.on_message_received(msg)
    return buf.getvalue().encode()


@SETTINGS
@given(frames=frame_arrays(), channel=st.sampled_from(["can0", "vcan1", 2, "7"]))
def test_format_equals_python_can_writer(frames: np.ndarray, channel: object) -> None:
    assert format_candump(frames, channel) == python_can_text(frames, channel)


@SETTINGS
@given(frames=frame_arrays(), cut=st.integers(0, 40))
def test_streaming_writer_equals_one_python_can_writer(
    tmp_path: Path, frames: np.ndarray, cut: int
) -> None:
    path = tmp_path / "s.log"
    with CandumpWriter(path) as writer:
        writer.write(frames[:cut])
        writer.write(frames[cut:])
    assert path.read_bytes() == python_can_text(frames)


def test_known_lines() -> None:
    f = np.zeros(4, dtype=FRAME_DTYPE)
    f["t"] = [1.5, 1.0, 2.0078125, 3.0]  # 1.0 < first: written as 1.5 (python-can quirk)
    f["id"] = [0x101, 0x1ABCDEF, 0x7, 0]
    f["dlc"] = [2, 1, 0, 1]
    f["flags"] = [0, 1, 2, 4]
    f["data"][0, :2] = [0xDE, 0xAD]
    f["data"][1, 0] = 0x42
    f["data"][3, 0] = 0x99
    assert format_candump(f) == (
        b"(1.500000) can0 101#DEAD R\n"
        b"(1.500000) can0 01ABCDEF#42 R\n"
        b"(2.007812) can0 007#R R\n"  # exact tie .0078125 rounds half to even
        b"(3.000000) can0 20000080#99\n"
    )


def test_candump_round_trip_is_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(11)
    n = 20_000
    f = np.zeros(n, dtype=FRAME_DTYPE)
    f["t"] = (1_700_000_000_000_000 + np.sort(rng.integers(0, 10**10, n))) / 1e6
    f["id"] = rng.integers(0, 0x800, n)
    f["dlc"] = rng.integers(0, 9, n)
    f["data"] = rng.integers(0, 256, (n, 8))
    f["data"][np.arange(8)[None, :] >= f["dlc"][:, None]] = 0
    write_candump(tmp_path / "r.log", f)
    back, notices = read_candump(tmp_path / "r.log")
    assert notices == []
    assert back.tobytes() == f.tobytes()


def test_uart_bytes_are_concatenated_packets() -> None:
    f = np.zeros(2, dtype=FRAME_DTYPE)
    f["id"] = [0x101, 0x180]
    f["dlc"] = [8, 3]
    f["data"][0] = range(8)
    f["data"][1, :3] = [1, 2, 3]
    assert uart_bytes(f) == encode_packet(0x101, bytes(range(8))) + encode_packet(0x180, b"\1\2\3")
    f["id"][0] = 0x1FFFF
    with pytest.raises(BenchError):
        uart_bytes(f)


def test_unwritable_path_is_bench_error(tmp_path: Path) -> None:
    with pytest.raises(BenchError, match="cannot write"):
        write_candump(tmp_path / "missing-dir" / "x.log", np.zeros(1, FRAME_DTYPE))
