"""protocol/acb3.dbc against the ICD and against our codec: cantools and protocol.can_codec
must read the same numbers out of the same frames."""

from __future__ import annotations

from pathlib import Path

import cantools
import pytest
from hypothesis import given, settings

from protocol.can_codec import encode_adc, encode_speed, encode_status
from protocol.dbc import DBC_PATH
from protocol.records import AdcSample, BoardStatus, SpeedRef
from tests.test_protocol_can import adc_samples, board_statuses, speed_refs

NOMINAL_SCALE = 2 * 9.80665 / 2**23  # ICD 1.1, m/s^2 per LSB
TICK = 100e-6  # ICD 1.1 / 1.3, s per timestamp tick


@pytest.fixture(scope="module")
def db() -> cantools.database.can.Database:
    return cantools.database.load_file(DBC_PATH)


def test_dbc_ships_inside_the_package() -> None:
    package_dir = Path(__file__).resolve().parents[1] / "protocol"
    assert package_dir / "acb3.dbc" == DBC_PATH.resolve()
    assert DBC_PATH.is_file()


def test_messages_match_icd(db: cantools.database.can.Database) -> None:
    expected = {
        0x100: "BOARD_STATUS",
        0x101: "ADC_SAMPLE_CH1",
        0x102: "ADC_SAMPLE_CH2",
        0x103: "ADC_SAMPLE_CH3",
        0x180: "SPEED_REF",
    }
    assert {m.frame_id: m.name for m in db.messages} == expected
    for message in db.messages:
        assert message.length == 8
        assert not message.is_extended_frame
        assert all(s.byte_order == "little_endian" for s in message.signals)
        assert message.get_signal_by_name("crc").start == 56
        assert "CRC-8" in message.get_signal_by_name("crc").comment
    state = db.get_message_by_name("BOARD_STATUS").get_signal_by_name("state")
    assert {int(k): str(v) for k, v in state.choices.items()} == {
        0: "BOOT",
        1: "RUN",
        2: "DEGRADED",
        3: "FAULT",
    }


def test_units_and_scales(db: cantools.database.can.Database) -> None:
    adc = db.get_message_by_name("ADC_SAMPLE_CH1")
    code = adc.get_signal_by_name("code")
    assert (code.length, code.is_signed, code.unit) == (24, True, "m/s^2")
    assert code.scale == NOMINAL_SCALE
    assert adc.get_signal_by_name("timestamp").scale == pytest.approx(TICK)
    speed = db.get_message_by_name("SPEED_REF").get_signal_by_name("speed")
    assert (speed.length, speed.is_signed, speed.unit, speed.scale) == (32, True, "m/s", 0.001)
    status = db.get_message_by_name("BOARD_STATUS")
    assert status.get_signal_by_name("temperature").is_signed
    assert status.get_signal_by_name("supply").scale == 0.1


@settings(max_examples=60, deadline=None)
@given(sample=adc_samples)
def test_adc_frames_decode_alike(db: cantools.database.can.Database, sample: AdcSample) -> None:
    can_id, data = encode_adc(sample)
    raw = db.decode_message(can_id, data, scaling=False)
    status_bits = raw["OVR"] | raw["SELFTEST"] << 1 | raw["REF"] << 2 | raw["CAL"] << 3
    assert raw["counter"] == sample.counter
    assert raw["code"] == sample.code
    assert status_bits | raw["status_reserved"] << 4 == sample.status
    assert raw["timestamp"] == sample.timestamp
    assert raw["crc"] == data[7]
    phys = db.decode_message(can_id, data)
    assert phys["code"] == pytest.approx(sample.code * NOMINAL_SCALE, rel=1e-12, abs=1e-15)
    assert phys["timestamp"] == pytest.approx(sample.timestamp * TICK, rel=1e-12)
    assert db.encode_message(can_id, raw, scaling=False) == data


@settings(max_examples=60, deadline=None)
@given(status=board_statuses)
def test_status_frames_decode_alike(
    db: cantools.database.can.Database, status: BoardStatus
) -> None:
    can_id, data = encode_status(status)
    raw = db.decode_message(can_id, data, scaling=False, decode_choices=False)
    assert raw == {
        "counter": status.counter,
        "state": status.state,
        "sample_rate": status.sample_rate,
        "temperature": status.temperature,
        "supply": status.supply,
        "errors": status.errors,
        "crc": data[7],
    }
    phys = db.decode_message(can_id, data, decode_choices=False)
    assert phys["supply"] == pytest.approx(status.supply_v)
    assert phys["temperature"] == status.temperature
    assert db.encode_message(can_id, raw, scaling=False) == data


@settings(max_examples=60, deadline=None)
@given(ref=speed_refs)
def test_speed_frames_decode_alike(db: cantools.database.can.Database, ref: SpeedRef) -> None:
    can_id, data = encode_speed(ref)
    raw = db.decode_message(can_id, data, scaling=False)
    assert raw == {
        "counter": ref.counter,
        "speed": ref.speed,
        "timestamp": ref.timestamp,
        "crc": data[7],
    }
    phys = db.decode_message(can_id, data)
    assert phys["speed"] == pytest.approx(ref.speed_mps, rel=1e-12)
    assert phys["timestamp"] == pytest.approx(ref.timestamp * TICK, rel=1e-12)
    assert db.encode_message(can_id, raw, scaling=False) == data
