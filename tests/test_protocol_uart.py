"""UART packets (ICD section 2) against a reference COBS encoder and bitwise CRC-16.

Broken packets are built so their outcome is certain, not merely likely: a single bit
flip before COBS is always caught by CRC-16 (or by the length rule if it hits dlc), a
body of at most 5 bytes decodes to at most 4 and so is always too short, a cut packet
always fails COBS or the length rule. Random noise is only used where the assertion
holds whatever the noise is.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.frames import FRAME_DTYPE, frames_from_raw
from protocol.layout import Outcome
from protocol.records import FLAG_UART, LinkError, RawFrame
from protocol.uart import MAX_BODY, Deframer, decode_packet, deframe_bytes, encode_packet
from tests.test_protocol_crc import crc16_ref

LINK_OUTCOMES = {Outcome.COBS_ERROR, Outcome.LENGTH_ERROR, Outcome.CRC16_ERROR}


def cobs_ref(data: bytes) -> bytes:
    """Textbook COBS for inputs shorter than 254 bytes (no 0xFF blocks needed)."""
    assert len(data) < 254
    out = bytearray()
    for block in data.split(b"\x00"):
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def raw_ref(can_id: int, data: bytes) -> bytes:
    """id_lo, id_hi, dlc, data, crc16_lo, crc16_hi: the packet before COBS."""
    head = bytes((can_id & 0xFF, can_id >> 8, len(data))) + data
    crc = crc16_ref(head)
    return head + bytes((crc & 0xFF, crc >> 8))


def packet_ref(can_id: int, data: bytes) -> bytes:
    return cobs_ref(raw_ref(can_id, data)) + b"\x00"


def run_deframer(
    buf: bytes, cuts: list[int], t: float = 0.0
) -> tuple[list[RawFrame], list[LinkError], Deframer]:
    """Feed buf cut at the given offsets, then flush; everything the receiver reported."""
    deframer = Deframer()
    frames: list[RawFrame] = []
    errors: list[LinkError] = []
    edges = [0, *sorted(c for c in cuts if 0 < c < len(buf)), len(buf)]
    for start, stop in itertools.pairwise(edges):
        f, e = deframer.feed(buf[start:stop], t)
        frames += f
        errors += e
    f, e = deframer.flush()
    return frames + f, errors + e, deframer


def assert_frames_equal(a: np.ndarray, b: np.ndarray) -> None:
    assert a.dtype == b.dtype == FRAME_DTYPE
    assert len(a) == len(b)
    for name in FRAME_DTYPE.names or ():
        assert np.array_equal(a[name], b[name], equal_nan=name == "t"), name


can_ids = st.integers(0, 0x7FF)
payloads = st.binary(max_size=8)


# --- single packets --------------------------------------------------------------------------


def test_hand_built_packet() -> None:
    # ADC ch1 frame 2A FE FF FF 00 34 12 5C (CRC-8 0x5C); packet before COBS:
    # 01 01 08 2A FE FF FF 00 34 12 5C | crc16 0x54E5 -> E5 54
    # COBS: 08 [01 01 08 2A FE FF FF] 06 [34 12 5C E5 54], then the 0x00 delimiter
    data = bytes.fromhex("2A FE FF FF 00 34 12 5C")
    packet = bytes.fromhex("08 01 01 08 2A FE FF FF 06 34 12 5C E5 54 00")
    assert encode_packet(0x101, data) == packet
    assert decode_packet(packet[:-1], 1.5) == RawFrame(1.5, 0x101, data, FLAG_UART)


@settings(max_examples=200)
@given(st.integers(0, 0xFFFF), payloads, st.floats(allow_nan=False))
def test_round_trip_matches_reference_encoding(can_id: int, data: bytes, t: float) -> None:
    packet = encode_packet(can_id, data)
    assert packet == packet_ref(can_id, data)
    assert packet.count(0) == 1
    frame = decode_packet(packet[:-1], t)
    assert frame == RawFrame(t, can_id, data, FLAG_UART)
    assert frame.flags & FLAG_UART


def test_encode_rejects_what_the_wire_cannot_carry() -> None:
    with pytest.raises(ValueError):
        encode_packet(0x10000, b"")
    with pytest.raises(ValueError):
        encode_packet(-1, b"")
    with pytest.raises(ValueError):
        encode_packet(0x100, bytes(9))


@settings(max_examples=300)
@given(st.binary(max_size=80), st.floats(allow_nan=False))
def test_decode_arbitrary_bytes_never_raises(body: bytes, t: float) -> None:
    result = decode_packet(body, t)
    if isinstance(result, LinkError):
        assert result.outcome in LINK_OUTCOMES
        assert result.raw == body
        assert result.t == t
        assert result.detail
    else:
        assert result.flags == FLAG_UART
        # accepted only if the body is exactly the reference encoding of that frame
        assert cobs_ref(raw_ref(result.can_id, result.data)) == body


@pytest.mark.parametrize(
    ("body", "outcome"),
    [
        (bytes.fromhex("05 01 02"), Outcome.COBS_ERROR),  # code 5 needs 4 more bytes
        (bytes.fromhex("02 01 00 03"), Outcome.COBS_ERROR),  # a zero inside a body
        (b"", Outcome.LENGTH_ERROR),
        (cobs_ref(bytes.fromhex("01 01 00 FF")), Outcome.LENGTH_ERROR),  # 4 bytes < header+crc
        # dlc says 8, only 2 data bytes present
        (
            cobs_ref(raw_ref(0x101, b"\x01\x02")[:2] + b"\x08" + raw_ref(0x101, b"\x01\x02")[3:]),
            Outcome.LENGTH_ERROR,
        ),
        # valid layout, CRC bytes swapped
        (
            cobs_ref(raw_ref(0x101, b"\x01\x02")[:-2] + raw_ref(0x101, b"\x01\x02")[:-3:-1]),
            Outcome.CRC16_ERROR,
        ),
    ],
)
def test_each_link_error_outcome(body: bytes, outcome: Outcome) -> None:
    result = decode_packet(body, 2.0)
    assert isinstance(result, LinkError)
    assert result == LinkError(2.0, outcome, body, result.detail)
    assert result.detail


def test_longer_dlc_is_passed_on_for_the_can_layer_to_reject() -> None:
    """A well-formed packet with dlc 12 is not a link error: it is a frame with the wrong
    DLC, which protocol.can_codec reports as WRONG_DLC."""
    data = bytes(range(1, 13))
    assert decode_packet(packet_ref(0x101, data)[:-1], 0.0) == RawFrame(0.0, 0x101, data, FLAG_UART)


# --- corrupted and truncated packets ---------------------------------------------------------

FIXED_FRAMES = [
    (0x101, bytes.fromhex("2A FE FF FF 00 34 12 5C")),
    (0x100, bytes.fromhex("07 01 C8 00 FB F0 FF 00")),
    (0x180, bytes.fromhex("03 FF FF FF FF 34 12 00")),
]


@pytest.mark.parametrize(("can_id", "data"), FIXED_FRAMES)
def test_every_single_byte_corruption_is_a_link_error(can_id: int, data: bytes) -> None:
    """Exhaustive: every position of the COBS body, every other byte value."""
    body = packet_ref(can_id, data)[:-1]
    for pos in range(len(body)):
        for value in range(1, 256):
            if value == body[pos]:
                continue
            bad = body[:pos] + bytes((value,)) + body[pos + 1 :]
            assert isinstance(decode_packet(bad, 0.0), LinkError), (pos, value)
        # a byte turned into 0x00 splits the packet: nothing of it may be accepted
        bad = body[:pos] + b"\x00" + body[pos + 1 :] + b"\x00"
        frames, errors, _ = run_deframer(bad, [])
        assert frames == []
        assert errors


@settings(max_examples=200)
@given(can_ids, payloads, st.data())
def test_single_bit_flip_is_crc16_or_length_error(
    can_id: int, data: bytes, draw: st.DataObject
) -> None:
    raw = bytearray(raw_ref(can_id, data))
    pos = draw.draw(st.integers(0, len(raw) - 1))
    raw[pos] ^= 1 << draw.draw(st.integers(0, 7))
    result = decode_packet(cobs_ref(bytes(raw)), 0.0)
    assert isinstance(result, LinkError)
    assert result.outcome == (Outcome.LENGTH_ERROR if pos == 2 else Outcome.CRC16_ERROR)


@settings(max_examples=100)
@given(can_ids, st.binary(min_size=8, max_size=8), st.data())
def test_truncated_packet_is_cobs_or_length_error(
    can_id: int, data: bytes, draw: st.DataObject
) -> None:
    body = packet_ref(can_id, data)[:-1]
    cut = body[: draw.draw(st.integers(1, len(body) - 1))]
    result = decode_packet(cut, 0.0)
    assert isinstance(result, LinkError)
    assert result.outcome in {Outcome.COBS_ERROR, Outcome.LENGTH_ERROR}


# --- streams ---------------------------------------------------------------------------------

nonzero = st.integers(1, 255)


@st.composite
def broken_items(draw: st.DrawFn) -> tuple[bytes, set[Outcome]]:
    """A delimited body that must be a link error, and the outcomes it may give."""
    kind = draw(st.sampled_from(["flip", "short", "truncated", "runaway"]))
    can_id, data = draw(can_ids), draw(payloads)
    if kind == "flip":
        raw = bytearray(raw_ref(can_id, data))
        pos = draw(st.integers(0, len(raw) - 1))
        raw[pos] ^= 1 << draw(st.integers(0, 7))
        expected = {Outcome.LENGTH_ERROR if pos == 2 else Outcome.CRC16_ERROR}
        return cobs_ref(bytes(raw)), expected
    if kind == "short":
        body = bytes(draw(st.lists(nonzero, min_size=1, max_size=5)))
        return body, {Outcome.COBS_ERROR, Outcome.LENGTH_ERROR}
    if kind == "truncated":
        body = cobs_ref(raw_ref(can_id, data.ljust(8, b"\x01")))
        return body[: draw(st.integers(1, len(body) - 1))], {
            Outcome.COBS_ERROR,
            Outcome.LENGTH_ERROR,
        }
    body = bytes(draw(st.lists(nonzero, min_size=MAX_BODY + 1, max_size=3 * MAX_BODY)))
    return body, {Outcome.LENGTH_ERROR}


@st.composite
def streams(draw: st.DrawFn) -> tuple[bytes, list[RawFrame], list[set[Outcome]]]:
    """Good packets and broken bodies in random order, with idle 0x00 runs between them."""
    buf = b"\x00" * draw(st.integers(0, 2))
    frames: list[RawFrame] = []
    outcomes: list[set[Outcome]] = []
    for _ in range(draw(st.integers(0, 12))):
        if draw(st.booleans()):
            can_id, data = draw(can_ids), draw(payloads)
            buf += packet_ref(can_id, data)
            frames.append(RawFrame(0.0, can_id, data, FLAG_UART))
        else:
            body, expected = draw(broken_items())
            buf += body + b"\x00"
            outcomes.append(expected)
        buf += b"\x00" * draw(st.integers(0, 2))
    return buf, frames, outcomes


@settings(max_examples=150)
@given(streams(), st.lists(st.integers(0, 400), max_size=8))
def test_stream_recovers_every_intact_packet_and_counts_every_broken_one(
    stream: tuple[bytes, list[RawFrame], list[set[Outcome]]], cuts: list[int]
) -> None:
    buf, expected_frames, expected_outcomes = stream
    frames, errors, deframer = run_deframer(buf, cuts)
    assert frames == expected_frames
    assert len(errors) == len(expected_outcomes)
    for error, allowed in zip(errors, expected_outcomes, strict=True):
        assert error.outcome in allowed
    assert deframer.ok == len(expected_frames)
    assert deframer.error_count == len(expected_outcomes)
    for outcome in LINK_OUTCOMES:
        assert deframer.errors[outcome] == sum(e.outcome == outcome for e in errors)
    array, batch_errors = deframe_bytes(buf, 0.0)
    assert_frames_equal(array, frames_from_raw(expected_frames))
    assert batch_errors == errors


@settings(max_examples=150)
@given(
    st.lists(st.tuples(st.binary(max_size=40), can_ids, payloads), max_size=8),
    st.binary(max_size=40),
)
def test_arbitrary_noise_between_packets(
    items: list[tuple[bytes, int, bytes]], trailing: bytes
) -> None:
    """Whatever the noise, a packet that follows a 0x00 is recovered, in order, and every
    non-empty stretch between delimiters is accounted for exactly once."""
    buf = b"".join(noise + b"\x00" + packet_ref(i, d) for noise, i, d in items) + trailing
    frames, errors, deframer = run_deframer(buf, [])
    expected = iter(frames)
    for _, can_id, data in items:  # subsequence check
        assert RawFrame(0.0, can_id, data, FLAG_UART) in expected
    segments = [s for s in buf.split(b"\x00") if s]
    assert len(frames) + len(errors) == len(segments)
    assert deframer.ok + deframer.error_count == len(segments)


@settings(max_examples=200)
@given(st.binary(max_size=300), st.lists(st.integers(0, 300), max_size=10))
def test_arbitrary_bytes_never_raise_and_chunking_does_not_matter(
    buf: bytes, cuts: list[int]
) -> None:
    frames, errors, _ = run_deframer(buf, cuts)
    one_frames, one_errors, _ = run_deframer(buf, [])
    assert frames == one_frames
    assert errors == one_errors
    array, batch_errors = deframe_bytes(buf, 0.0)
    assert_frames_equal(array, frames_from_raw(frames))
    assert batch_errors == errors
    assert all(e.outcome in LINK_OUTCOMES for e in errors)


@settings(max_examples=100)
@given(
    st.lists(
        st.one_of(
            st.tuples(can_ids, payloads).map(lambda p: packet_ref(*p)),
            st.binary(max_size=20),
            st.lists(nonzero, min_size=MAX_BODY - 2, max_size=MAX_BODY + 2).map(bytes),
        ),
        max_size=10,
    ).map(b"".join),
    st.lists(st.integers(0, 600), max_size=12),
)
def test_chunked_feeding_equals_one_shot_capture(buf: bytes, cuts: list[int]) -> None:
    frames, errors, _ = run_deframer(buf, cuts)
    array, batch_errors = deframe_bytes(buf, 0.0)
    assert_frames_equal(array, frames_from_raw(frames))
    assert batch_errors == errors


def test_receiver_started_mid_packet_resynchronises() -> None:
    first = packet_ref(0x101, bytes(range(1, 9)))
    good = [packet_ref(0x102, bytes(range(8))), packet_ref(0x180, b"\xff" * 8)]
    frames, errors, _ = run_deframer(first[6:] + b"".join(good), [])
    assert [f.can_id for f in frames] == [0x102, 0x180]
    assert len(errors) == 1
    assert errors[0].raw == first[6:-1]


def test_packet_gets_the_time_its_delimiter_arrived() -> None:
    packet = packet_ref(0x101, bytes(8))
    deframer = Deframer()
    assert deframer.feed(packet[:5], 1.0) == ([], [])
    assert deframer.pending == 5
    frames, errors = deframer.feed(packet[5:], 2.0)
    assert frames == [RawFrame(2.0, 0x101, bytes(8), FLAG_UART)]
    assert errors == []


def test_empty_packets_are_idle_not_errors() -> None:
    deframer = Deframer()
    assert deframer.feed(b"\x00" * 10, 0.0) == ([], [])
    assert deframer.flush() == ([], [])
    assert deframer.ok == deframer.error_count == 0
    array, errors = deframe_bytes(b"\x00" * 10)
    assert len(array) == 0
    assert errors == []


def test_runaway_packet_is_reported_once_and_memory_stays_bounded() -> None:
    deframer = Deframer()
    noise = bytes(range(1, 251)) * 4  # 1000 bytes without a delimiter
    errors: list[LinkError] = []
    for i, byte in enumerate(noise):
        f, e = deframer.feed(bytes((byte,)), float(i))
        assert f == []
        errors += e
        assert deframer.pending <= MAX_BODY
    assert len(errors) == 1
    assert errors[0].outcome == Outcome.LENGTH_ERROR
    assert errors[0].raw == noise[:MAX_BODY]
    assert errors[0].t == float(MAX_BODY)  # reported when the bound was overrun
    frames, e = deframer.feed(b"\x00" + packet_ref(0x103, b"\x01\x02\x03"), 5000.0)
    assert frames == [RawFrame(5000.0, 0x103, b"\x01\x02\x03", FLAG_UART)]
    assert e == []
    assert deframer.discarded == len(noise)
    assert deframer.errors[Outcome.LENGTH_ERROR] == 1


def test_flush_reports_the_unterminated_tail() -> None:
    packet = packet_ref(0x101, bytes(8))
    deframer = Deframer()
    deframer.feed(packet[:-1], 3.0)  # the whole body, but its 0x00 never came
    frames, errors = deframer.flush()
    assert frames == []
    assert errors == [LinkError(3.0, Outcome.LENGTH_ERROR, packet[:-1], errors[0].detail)]
    assert deframer.flush() == ([], [])  # reset: reported once
    frames, _ = deframer.feed(packet, 4.0)
    assert len(frames) == 1
    array, batch_errors = deframe_bytes(packet[:-1], 3.0)
    assert len(array) == 0
    assert batch_errors == errors


def test_deframe_bytes_defaults_and_mixed_lengths_keep_order() -> None:
    ids = [0x101, 0x7FF, 0x102, 0x000, 0x180]
    datas = [bytes(8), b"", bytes(range(1, 9)), b"\x05", b"\x00" * 8]
    buf = b"".join(packet_ref(i, d) for i, d in zip(ids, datas, strict=True))
    array, errors = deframe_bytes(buf)
    assert errors == []
    assert array.dtype == FRAME_DTYPE
    assert array["id"].tolist() == ids
    assert array["dlc"].tolist() == [len(d) for d in datas]
    assert (array["flags"] == FLAG_UART).all()
    assert all(math.isnan(t) for t in array["t"])
    assert [bytes(row[: len(d)]) for row, d in zip(array["data"], datas, strict=True)] == datas
