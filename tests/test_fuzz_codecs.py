"""Fuzzing the decode path and the MCAP reader with hypothesis.

* Board-like frames with valid CRCs but wild contents (counters, board timestamps, status
  bytes, receive times that are NaN, infinite, huge, negative or going backwards), cut
  into arbitrary batches: the pipeline never raises, emits samples in strictly increasing
  ``n``, and accounts for every frame.
* A recorded MCAP file truncated anywhere and with bytes flipped anywhere: the reader
  either refuses it with one ``BenchError`` line or yields what is intact; replaying it
  never raises, and loses no frame without saying so.

(Round trips of the scalar codecs, CRCs, COBS framing and the candump parser are held by
tests/test_protocol_*.py and tests/test_devices_candump.py.)
"""

from __future__ import annotations

import itertools
import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.config import Config
from bench.errors import BenchError
from bench.pipeline.steps import Pipeline, StepOutput
from bench.sinks.base import Sink
from devices.base import SourceBatch
from protocol.crc import frame_crc8_batch
from protocol.frames import FRAME_DTYPE, empty_frames
from protocol.layout import DEFAULT_BASE, SPEED_REF_ID

SCALE = float(os.environ.get("BENCH_FUZZ_SCALE", "1"))


def _settings(n: int) -> settings:
    return settings(
        max_examples=max(1, int(n * SCALE)),
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )


# --------------------------------------------------------------------------- frames
IDS = st.sampled_from(
    [DEFAULT_BASE, DEFAULT_BASE + 1, DEFAULT_BASE + 2, DEFAULT_BASE + 3, SPEED_REF_ID, 0x7FF, 0]
)
TIMES = st.one_of(
    st.floats(min_value=0.0, max_value=10.0),
    st.sampled_from([float("nan"), float("inf"), -float("inf"), 1e300, -5.0, 0.0, 1.8e10]),
)


@st.composite
def frame_rows(draw: st.DrawFn) -> tuple[float, int, int, bytes, bool]:
    can_id = draw(IDS)
    body = draw(st.binary(min_size=7, max_size=7))
    if draw(st.booleans()):  # a plausible ADC/status/speed layout, fields anywhere in range
        counter = draw(st.integers(0, 255))
        ts = draw(st.one_of(st.integers(0, 65535), st.sampled_from([0, 65535, 32768])))
        if can_id == DEFAULT_BASE:  # status: counter, state, rate u16, temp, supply, errors
            rate = draw(st.sampled_from([0, 1, 50, 200, 1000, 65535]))
            body = struct.pack("<BBH", counter, draw(st.integers(0, 255)), rate) + body[4:]
        else:
            body = bytes([counter]) + body[1:5] + struct.pack("<H", ts)
    dlc = draw(st.sampled_from([8, 8, 8, 8, 0, 7, 15]))
    crc_ok = draw(st.integers(0, 9)) > 0
    return draw(TIMES), can_id, dlc, body, crc_ok


@st.composite
def streams(draw: st.DrawFn) -> tuple[np.ndarray, list[int]]:
    rows = draw(st.lists(frame_rows(), min_size=1, max_size=120))
    frames = np.zeros(len(rows), dtype=FRAME_DTYPE)
    for i, (t, can_id, dlc, body, _) in enumerate(rows):
        frames[i]["t"] = t
        frames[i]["id"] = can_id
        frames[i]["dlc"] = dlc
        frames[i]["data"][:7] = np.frombuffer(body, dtype=np.uint8)
    crc = frame_crc8_batch(frames["id"].astype(np.int64), np.ascontiguousarray(frames["data"]))
    ok = np.array([r[4] for r in rows])
    frames["data"][:, 7] = np.where(ok, crc, crc ^ 0x5A)
    cuts = sorted(set(draw(st.lists(st.integers(0, len(rows)), max_size=6))))
    return frames, cuts


@_settings(150)
@given(streams(), st.sampled_from([200, 1000, 50]))
def test_pipeline_takes_any_board_like_stream(
    stream: tuple[np.ndarray, list[int]], rate: int
) -> None:
    frames, cuts = stream
    p = Pipeline(Config(sample_rate_hz=rate))
    bounds = [0, *cuts, len(frames)]
    outs = [p.process(SourceBatch(frames[a:b])) for a, b in itertools.pairwise(bounds)]
    outs.append(p.finish())
    n = np.concatenate([o.results["n"] for o in outs])
    assert np.all(np.diff(n) > 0), "samples must come out once each, in n order"
    assert p.seq == len(frames) == p.stats.frames
    for o in outs:  # every result row is a sample that was emitted
        assert len(o.results) == len(o.samples)


# --------------------------------------------------------------------------- MCAP
@dataclass(frozen=True)
class Recorded:
    data: bytes  # the MCAP file
    frames: np.ndarray  # the emulator's frames the live run wrote into it


@pytest.fixture(scope="module")
def recorded_mcap(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    """A small MCAP file as a live run writes it (frames, samples, results, events)."""
    from bench.mcaplog.sink import McapSink
    from devices.emulator import scenario_from_dict, simulate

    sim = simulate(scenario_from_dict({"duration_s": 0.5, "sample_rate_hz": 200, "seed": 3}))
    path = tmp_path_factory.mktemp("mcap") / "run.mcap"
    p = Pipeline(Config())
    sink = McapSink(path, Config(), {"source": "fuzz"}, chunk_size=2048)
    for i in range(0, len(sim.frames), 40):
        sink.write(p.process(SourceBatch(sim.frames[i : i + 40])))
    sink.write(p.finish())
    sink.close()
    assert sink.error is None
    return Recorded(path.read_bytes(), sim.frames.copy())


class _Frames(Sink):
    """A sink keeping the frames each replay step was given."""

    def __init__(self) -> None:
        self.parts: list[np.ndarray] = []

    def write(self, step: StepOutput) -> None:
        if step.batch is not None:
            self.parts.append(step.batch.frames)


def _replayed(path: Path) -> tuple[np.ndarray, list[str]] | None:
    """The frames a replay of ``path`` processed and its notices; None when the file is
    refused, which must be one line, or yields no frame (``bench replay`` refuses that in
    one line too: bench.replay.run.no_frames)."""
    from bench.mcaplog.reader import McapLog
    from bench.replay.run import replay
    from devices.formats import open_log

    try:
        with McapLog(path) as log:
            log.message_counts()
            log.metadata_dict()
            log.read_frames()
            log.verify()
        source = open_log(path)
    except BenchError as exc:
        assert str(exc).strip() and "\n" not in str(exc).strip()
        return None
    kept = _Frames()
    out = replay(source, Config(), [kept], collect=True)
    frames = np.concatenate(kept.parts) if kept.parts else empty_frames()
    assert out.pipeline.stats.frames == len(frames)
    return (frames, out.notices) if len(frames) else None


def _lost_only_with_notice(got: tuple[np.ndarray, list[str]], recorded: Recorded) -> None:
    """The frames read are recorded ones in their order (whole chunks may be missing), and
    when any is missing the replay says so."""
    frames, notices = got
    want = [r.tobytes() for r in recorded.frames]
    it = iter(want)
    assert all(f.tobytes() in it for f in frames), "a frame the run did not record"
    if len(frames) < len(want):
        assert notices, f"{len(want) - len(frames)} of {len(want)} frames lost silently"


@_settings(80)
@given(data=st.data())
def test_mcap_truncated_anywhere_reads_what_is_intact(
    recorded_mcap: Recorded, tmp_path_factory: pytest.TempPathFactory, data: Any
) -> None:
    cut = data.draw(st.integers(0, len(recorded_mcap.data) - 1))
    path = tmp_path_factory.mktemp("cut") / "cut.mcap"
    path.write_bytes(recorded_mcap.data[:cut])
    got = _replayed(path)
    if got is not None:  # a prefix of what was recorded, and the cut is reported
        frames = got[0]
        assert frames.tobytes() == recorded_mcap.frames[: len(frames)].tobytes()
        _lost_only_with_notice(got, recorded_mcap)


@_settings(80)
@given(data=st.data())
def test_mcap_with_flipped_bytes_loses_nothing_silently(
    recorded_mcap: Recorded, tmp_path_factory: pytest.TempPathFactory, data: Any
) -> None:
    buf = bytearray(recorded_mcap.data)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(buf) - 1))
        buf[i] = data.draw(st.sampled_from([0x00, 0xFF, buf[i] ^ 0x01, buf[i] ^ 0x80]))
    path = tmp_path_factory.mktemp("flip") / "flip.mcap"
    path.write_bytes(bytes(buf))
    got = _replayed(path)
    if got is not None:
        _lost_only_with_notice(got, recorded_mcap)


def _records(data: bytes, opcode: int) -> list[int]:
    """Offsets of the data section's records of ``opcode`` (MCAP: opcode u8, length u64),
    walked from the magic to DataEnd (0x0F)."""
    pos, out = 8, []
    while pos + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        if op == 0x0F:
            break
        if op == opcode:
            out.append(pos)
        pos += 9 + length
    return out


@pytest.mark.parametrize(("opcode", "what"), [(0x07, "MessageIndex"), (0x04, "Channel")])
def test_mcap_with_a_channel_id_flipped_loses_nothing_silently(
    recorded_mcap: Recorded, tmp_path: Path, opcode: int, what: str
) -> None:
    """A one-bit flip in the channel id (the body's first u16) of a chunk's MessageIndex
    hid that chunk's frames, and of a Channel record raised JSONDecodeError: now the index
    is checked against the chunk and a message that is not its topic's JSON is a notice."""
    offsets = _records(recorded_mcap.data, opcode)
    assert len(offsets) >= 3, what
    for at in offsets[:12]:
        for bit in (0x01, 0x02, 0x100):
            buf = bytearray(recorded_mcap.data)
            struct.pack_into("<H", buf, at + 9, struct.unpack_from("<H", buf, at + 9)[0] ^ bit)
            path = tmp_path / f"{what}-{at}-{bit}.mcap"
            path.write_bytes(bytes(buf))
            got = _replayed(path)
            if opcode == 0x07:  # the chunks are whole: every frame is read
                assert got is not None and len(got[0]) == len(recorded_mcap.frames), (at, bit)
            if got is not None:  # a Channel's damage may also be refused, in one line
                _lost_only_with_notice(got, recorded_mcap)


@_settings(40)
@given(st.binary(max_size=400))
def test_mcap_magic_then_garbage_is_refused(
    tmp_path_factory: pytest.TempPathFactory, blob: bytes
) -> None:
    path = tmp_path_factory.mktemp("garbage") / "g.mcap"
    path.write_bytes(b"\x89MCAP0\r\n" + blob)
    assert _replayed(path) is None  # refused: garbage holds no frame


@pytest.mark.parametrize("bad_t", [float("inf"), float("nan"), 1e300, -1.0])
@pytest.mark.parametrize("batch", [1, 4096], ids=["live-sized", "replay-sized"])
def test_absurd_receive_time_on_any_frame_is_survived(bad_t: float, batch: int) -> None:
    """One corrupt receive time (a damaged log line, a broken clock) on a SPEED_REF, status
    or ADC frame: fed live-sized (one frame at a time) or in replay batches, the pipeline
    carries on and the rest of the stream is assembled as before."""
    from devices.emulator import scenario_from_dict, simulate

    frames = simulate(scenario_from_dict({"duration_s": 2.0, "sample_rate_hz": 200})).frames
    frames["t"] += 1.7e9
    clean = _run(frames, batch)
    for kind_id in (SPEED_REF_ID, DEFAULT_BASE, DEFAULT_BASE + 2):
        f = frames.copy()
        at = int(np.flatnonzero(f["id"] == kind_id)[len(np.flatnonzero(f["id"] == kind_id)) // 2])
        f["t"][at] = bad_t
        with np.errstate(invalid="raise", over="raise"):  # no silent invalid casts either
            n = _run(f, batch)
        assert n >= clean - 2, f"id 0x{kind_id:X}, t={bad_t}: {n} of {clean} samples"


def _run(frames: np.ndarray, batch: int) -> int:
    p = Pipeline(Config(sample_rate_hz=200))
    n = sum(
        len(p.process(SourceBatch(frames[i : i + batch])).results)
        for i in range(0, len(frames), batch)
    )
    return n + len(p.finish().results)
