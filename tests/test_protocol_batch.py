"""The batch decode (protocol.batch), the bench's only decoder, row by row for every field:
each frame generated from a message (or damaged in a known way) must decode to that
message (or that failure). test_protocol_can.py pins it to the ICD's byte tables.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.batch import DecodedBatch, decode_batch
from protocol.can_codec import encode_adc, encode_speed, encode_status
from protocol.frames import FRAME_DTYPE, frames_from_raw
from protocol.layout import FrameKind, Outcome
from protocol.records import (
    AdcSample,
    BoardStatus,
    RawFrame,
    SpeedRef,
)
from tests.test_protocol_can import adc_samples, board_statuses, speed_refs

Expected = AdcSample | BoardStatus | SpeedRef | Outcome


@st.composite
def frames(draw: st.DrawFn, base: int) -> tuple[RawFrame, Expected]:
    """One frame and what it must decode to: a valid one its message; a corrupted one (one
    byte changed: CRC-8 catches every burst of 8 bits or fewer) CRC_MISMATCH; a wrong length
    WRONG_DLC; a foreign id UNKNOWN_ID; in roughly equal measure."""
    message = draw(st.one_of(adc_samples, board_statuses, speed_refs))
    if isinstance(message, AdcSample):
        can_id, data = encode_adc(message, base)
    elif isinstance(message, BoardStatus):
        can_id, data = encode_status(message, base)
    else:
        can_id, data = encode_speed(message)
    expected: Expected = message
    variant = draw(st.sampled_from(["valid", "corrupt", "dlc", "unknown"]))
    if variant == "corrupt":
        buf = bytearray(data)
        buf[draw(st.integers(0, 7))] ^= draw(st.integers(1, 255))
        data, expected = bytes(buf), Outcome.CRC_MISMATCH
    elif variant == "dlc":  # classical short frames and CAN FD long ones
        n = draw(st.integers(0, 16).filter(lambda n: n != 8))
        data, expected = (data * 2)[:n], Outcome.WRONG_DLC
    elif variant == "unknown":
        can_id = draw(st.integers(0, 0x7FF).filter(lambda i: i != 0x180 and not 0 <= i - base <= 3))
        expected = Outcome.UNKNOWN_ID
    t = draw(st.floats(0, 1e9, allow_nan=False))
    return RawFrame(t, can_id, data), expected


def assert_row_is(batch: DecodedBatch, i: int, expected: Expected) -> None:
    if isinstance(expected, Outcome):
        assert batch.outcome[i] == expected
        assert not batch.ok[i]
        if expected is Outcome.UNKNOWN_ID:
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
def test_each_row_decodes_to_the_message_encoded_or_its_failure(
    case: tuple[int, list[tuple[RawFrame, Expected]]],
) -> None:
    base, rows = case
    batch = decode_batch(frames_from_raw([frame for frame, _ in rows]), base)
    assert len(batch) == len(rows)
    for i, (_, expected) in enumerate(rows):
        assert_row_is(batch, i, expected)


@settings(max_examples=30)
@given(st.lists(frames(0x100), max_size=40))
def test_a_strided_view_decodes_like_its_frames(rows: list[tuple[RawFrame, Expected]]) -> None:
    """A source may hand over a view (every other frame of a larger array)."""
    batch = decode_batch(frames_from_raw([frame for frame, _ in rows])[::2])
    assert len(batch) == len(rows[::2])
    for i, (_, expected) in enumerate(rows[::2]):
        assert_row_is(batch, i, expected)


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


def test_base_next_to_speed_ref_id_gives_speed_ref() -> None:
    """With BASE 0x17F the SPEED_REF id 0x180 is also BASE+1: the ICD's fixed SPEED_REF id
    wins, so the batch must say SPEED, channel 0."""
    rows = [RawFrame(0.0, *encode_speed(SpeedRef(1, 2, 3)))]
    batch = decode_batch(frames_from_raw(rows), base=0x17F)
    assert batch.kind[0] == FrameKind.SPEED
    assert batch.channel[0] == 0
    assert batch.speed[0] == 2
