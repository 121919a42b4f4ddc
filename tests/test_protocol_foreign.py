"""Extended, remote and error frames can share the bus but never come from the board (ICD 1)."""

from __future__ import annotations

import pytest

from protocol.batch import decode_batch
from protocol.can_codec import encode_adc
from protocol.frames import frames_from_raw
from protocol.layout import FrameKind, Outcome
from protocol.records import FLAG_ERROR, FLAG_EXTENDED, FLAG_REMOTE, AdcSample, RawFrame
from tests.helpers import UnknownId, decode


@pytest.mark.parametrize("flag", [FLAG_EXTENDED, FLAG_REMOTE, FLAG_ERROR])
def test_flagged_frame_with_a_board_id_is_unknown_not_adc(flag):
    can_id, data = encode_adc(AdcSample(1, 5, 1234, 0, 77))  # a perfectly valid ch1 payload
    assert isinstance(decode(can_id, data, flags=flag), UnknownId)
    dec = decode_batch(
        frames_from_raw([RawFrame(0.0, can_id, data, flag), RawFrame(0.0, can_id, data, 0)])
    )
    assert dec.kind.tolist() == [FrameKind.OTHER, FrameKind.ADC]
    assert dec.outcome.tolist() == [Outcome.UNKNOWN_ID, Outcome.OK]
