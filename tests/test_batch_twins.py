"""The two decoders of protocol.batch are twins, and the pair-table CRC check is the CRC.

A live step decodes a few frames in plain Python, a replay batch with numpy views into
the frame records; both must give the same columns (dtype and bytes) for any bytes at
all, including foreign, short, extended and corrupted frames. test_protocol_batch pins
decode_batch to the scalar codec, so agreement here carries that over to both paths.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from protocol.batch import DECODED_DTYPE, SCALAR_MAX, decode_batch, decode_scalar, decode_vector
from protocol.crc import frame_crc8, frame_crc8_residue
from protocol.frames import FRAME_DTYPE
from protocol.layout import SPEED_REF_ID

ids = st.one_of(
    st.sampled_from([0x100, 0x101, 0x102, 0x103, 0x104, 0xFF, SPEED_REF_ID, 0x17F, 0x200]),
    st.integers(0, 0x7FF),
    st.integers(0, 2**32 - 1),
)


@st.composite
def frame_arrays(draw: st.DrawFn) -> np.ndarray:
    n = draw(st.integers(0, 3 * SCALAR_MAX))
    frames = np.zeros(n, dtype=FRAME_DTYPE)
    frames["t"] = draw(hnp.arrays(np.float64, n, elements=st.floats(allow_nan=True)))
    frames["id"] = draw(st.lists(ids, min_size=n, max_size=n))
    frames["dlc"] = draw(
        st.lists(st.sampled_from([8, 8, 8, 0, 7, 9, 64, 255]), min_size=n, max_size=n)
    )
    frames["flags"] = draw(
        st.lists(st.sampled_from([0, 0, 0, 1, 2, 4, 8, 16]), min_size=n, max_size=n)
    )
    frames["data"] = draw(hnp.arrays(np.uint8, (n, 8)))
    # most frames carry their right CRC, so the decoded fields are exercised too
    for i in range(n):
        if draw(st.booleans()):
            frames["data"][i, 7] = frame_crc8(int(frames["id"][i]), bytes(frames["data"][i, :7]))
    return frames


def columns(batch) -> list[tuple[str, np.dtype, bytes]]:
    return [
        (name, getattr(batch, name).dtype, np.ascontiguousarray(getattr(batch, name)).tobytes())
        for name in DECODED_DTYPE.names
    ]


@settings(max_examples=150, deadline=None)
@given(frame_arrays(), st.sampled_from([0x100, 0x17F, 0x180, 0x200, 0]))
def test_scalar_and_vector_decode_are_twins(frames: np.ndarray, base: int) -> None:
    scalar, vector = decode_scalar(frames, base), decode_vector(frames, base)
    assert len(scalar) == len(vector) == len(frames)
    assert columns(scalar) == columns(vector)
    assert columns(decode_batch(frames, base)) == columns(vector)


@settings(max_examples=100, deadline=None)
@given(frame_arrays())
def test_twins_agree_on_strided_slices(frames: np.ndarray) -> None:
    """A source may hand over a view (every other frame of a larger array)."""
    view = frames[::2]
    assert columns(decode_scalar(view)) == columns(decode_vector(view))


@settings(max_examples=100, deadline=None)
@given(frame_arrays())
def test_pair_table_residue_is_zero_exactly_where_the_crc_is_right(frames: np.ndarray) -> None:
    data = frames["data"]
    pairs = np.ascontiguousarray(data).view("<u2")
    residue = frame_crc8_residue(
        ((frames["id"] & 0xFFFF).astype(np.uint16), *(pairs[:, k] for k in range(4)))
    )
    expected = [
        frame_crc8(int(i), bytes(row[:7])) ^ int(row[7])
        for i, row in zip(frames["id"], data, strict=True)
    ]
    assert residue.dtype == np.uint8
    assert residue.tolist() == expected
