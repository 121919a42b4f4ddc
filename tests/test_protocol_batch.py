"""The batch decode (protocol.batch) equals the per-frame codec, row by row, for every field.

The scalar codec is itself pinned to the ICD byte tables in test_protocol_can.py, so
agreement here carries those hand-checked expectations over to the batch path.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.batch import DecodedBatch, decode_batch
from protocol.can_codec import decode, encode_adc, encode_speed, encode_status
from protocol.frames import FRAME_DTYPE, frames_from_raw
from protocol.layout import FrameKind, Outcome
from protocol.records import (
    AdcSample,
    BoardStatus,
    CrcMismatch,
    RawFrame,
    SpeedRef,
    UnknownId,
    WrongDlc,
)
from tests.test_protocol_can import adc_samples, board_statuses, speed_refs

ERROR_OUTCOME = {
    UnknownId: Outcome.UNKNOWN_ID,
    WrongDlc: Outcome.WRONG_DLC,
    CrcMismatch: Outcome.CRC_MISMATCH,
}


@st.composite
def frames(draw: st.DrawFn, base: int) -> RawFrame:
    """One frame: valid, corrupted, wrong length or foreign, in roughly equal measure."""
    message = draw(st.one_of(adc_samples, board_statuses, speed_refs))
    if isinstance(message, AdcSample):
        can_id, data = encode_adc(message, base)
    elif isinstance(message, BoardStatus):
        can_id, data = encode_status(message, base)
    else:
        can_id, data = encode_speed(message)
    variant = draw(st.sampled_from(["valid", "corrupt", "dlc", "unknown"]))
    if variant == "corrupt":
        buf = bytearray(data)
        buf[draw(st.integers(0, 7))] ^= draw(st.integers(1, 255))
        data = bytes(buf)
    elif variant == "dlc":  # classical short frames and CAN FD long ones
        n = draw(st.integers(0, 16).filter(lambda n: n != 8))
        data = (data * 2)[:n]
    elif variant == "unknown":
        can_id = draw(st.integers(0, 0x7FF).filter(lambda i: i != 0x180 and not 0 <= i - base <= 3))
    t = draw(st.floats(0, 1e9, allow_nan=False))
    return RawFrame(t, can_id, data)


def assert_row_equals_scalar(batch: DecodedBatch, i: int, frame: RawFrame, base: int) -> None:
    expected = decode(frame.can_id, frame.data, base)
    if isinstance(expected, UnknownId | WrongDlc | CrcMismatch):
        assert batch.outcome[i] == ERROR_OUTCOME[type(expected)]
        assert not batch.ok[i]
        if isinstance(expected, UnknownId):
            assert batch.kind[i] == FrameKind.OTHER
        return
    assert batch.outcome[i] == Outcome.OK
    assert batch.ok[i]
    assert batch.counter[i] == expected.counter
    if isinstance(expected, AdcSample):
        assert batch.kind[i] == FrameKind.ADC
        assert batch.channel[i] == expected.channel
        assert batch.code[i] == expected.code
        assert batch.status[i] == expected.status
        assert batch.timestamp[i] == expected.timestamp
    elif isinstance(expected, BoardStatus):
        assert batch.kind[i] == FrameKind.STATUS
        assert batch.channel[i] == 0
        assert batch.state[i] == expected.state
        assert batch.sample_rate[i] == expected.sample_rate
        assert batch.temperature[i] == expected.temperature
        assert batch.supply[i] == expected.supply
        assert batch.errors[i] == expected.errors
    else:
        assert isinstance(expected, SpeedRef)
        assert batch.kind[i] == FrameKind.SPEED
        assert batch.channel[i] == 0
        assert batch.speed[i] == expected.speed
        assert batch.timestamp[i] == expected.timestamp


@settings(max_examples=60)
@given(
    st.sampled_from([0x100, 0x200]).flatmap(
        lambda base: st.tuples(st.just(base), st.lists(frames(base), max_size=40))
    )
)
def test_decode_batch_equals_scalar_decode(case: tuple[int, list[RawFrame]]) -> None:
    base, rows = case
    array = frames_from_raw(rows)
    batch = decode_batch(array, base)
    assert len(batch) == len(rows)
    for i, frame in enumerate(rows):
        assert_row_equals_scalar(batch, i, frame, base)


@settings(max_examples=30)
@given(st.lists(frames(0x100), max_size=40))
def test_a_strided_view_decodes_like_its_frames(rows: list[RawFrame]) -> None:
    """A source may hand over a view (every other frame of a larger array)."""
    batch = decode_batch(frames_from_raw(rows)[::2])
    assert len(batch) == len(rows[::2])
    for i, frame in enumerate(rows[::2]):
        assert_row_equals_scalar(batch, i, frame, 0x100)


def test_empty_batch() -> None:
    batch = decode_batch(np.zeros(0, dtype=FRAME_DTYPE))
    assert len(batch) == 0


def test_field_extremes_survive_the_dtypes() -> None:
    rows = [
        RawFrame(0.0, *encode_adc(AdcSample(1, 255, -(2**23), 0xFF, 0xFFFF))),
        RawFrame(0.0, *encode_adc(AdcSample(3, 0, 2**23 - 1, 0, 0))),
        RawFrame(0.0, *encode_speed(SpeedRef(0, -(2**31), 0xFFFF))),
        RawFrame(0.0, *encode_speed(SpeedRef(0, 2**31 - 1, 0))),
        RawFrame(0.0, *encode_status(BoardStatus(255, 3, 0xFFFF, -128, 255, 255))),
    ]
    batch = decode_batch(frames_from_raw(rows))
    assert batch.ok.all()
    assert batch.code[:2].tolist() == [-(2**23), 2**23 - 1]
    assert batch.speed[2:4].tolist() == [-(2**31), 2**31 - 1]
    assert batch.temperature[4] == -128
    assert batch.sample_rate[4] == 0xFFFF


def test_base_next_to_speed_ref_id_gives_scalar_channel() -> None:
    """With BASE 0x17F the SPEED_REF id 0x180 is also BASE+1; like the scalar decoder
    (classify_id checks SPEED_REF first) the batch must say SPEED, channel 0."""
    rows = [RawFrame(0.0, *encode_speed(SpeedRef(1, 2, 3)))]
    batch = decode_batch(frames_from_raw(rows), base=0x17F)
    assert decode(0x180, rows[0].data, base=0x17F) == SpeedRef(1, 2, 3)
    assert batch.kind[0] == FrameKind.SPEED
    assert batch.channel[0] == 0
    assert batch.speed[0] == 2
