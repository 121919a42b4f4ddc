"""SerialSource on a pseudo-terminal: the test writes the board's byte stream to the master.

Broken packets are built so that they are certain link errors (see test_protocol_uart):
a packet cut in half, a short body, and a single flipped bit before COBS (always caught by
CRC-16, or by the length rule when it hits the dlc byte).
"""

from __future__ import annotations

import contextlib
import os
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from cobs import cobs

from bench.errors import BenchError
from devices.base import SourceBatch
from devices.serial_port import DEFAULT_BAUD, SerialSource
from protocol.can_codec import encode_adc
from protocol.crc import crc16_ccitt_false
from protocol.records import FLAG_UART, AdcSample
from tests.helpers import decode, read_until, records

pytestmark = pytest.mark.skipif(os.name != "posix", reason="needs a pty")


@pytest.fixture
def pty() -> Iterator[tuple[int, str]]:
    master, slave = os.openpty()
    tty.setraw(master)
    path = os.ttyname(slave)
    yield master, path
    for fd in (master, slave):
        with contextlib.suppress(OSError):  # a test may have closed it already
            os.close(fd)


def packet(sample: AdcSample) -> bytes:
    can_id, data = encode_adc(sample)
    raw = bytes((can_id & 0xFF, can_id >> 8, len(data))) + data
    crc = crc16_ccitt_false(raw)
    return cobs.encode(raw + bytes((crc & 0xFF, crc >> 8))) + b"\0"


def flipped(sample: AdcSample, bit: int) -> bytes:
    can_id, data = encode_adc(sample)
    raw = bytearray((can_id & 0xFF, can_id >> 8, len(data))) + data
    crc = crc16_ccitt_false(bytes(raw))
    raw += bytes((crc & 0xFF, crc >> 8))
    raw[bit // 8] ^= 1 << (bit % 8)
    return cobs.encode(bytes(raw)) + b"\0"


def n_frames(batches: list[SourceBatch]) -> int:
    return sum(len(b.frames) for b in batches)


def test_pty_round_trip_recovers_intact_and_counts_broken(pty: tuple[int, str]) -> None:
    master, path = pty
    src = SerialSource(path)
    samples = [
        AdcSample(1 + k % 3, k % 256, (k * 7919) % 100_000 - 50_000, 0, k) for k in range(300)
    ]
    rng = np.random.default_rng(4)
    stream = [b"\x13\x11tail-of-a-packet\0"]  # the receiver joins mid-packet: 1 error
    broken = 1
    for k, s in enumerate(samples):
        stream.append(packet(s))
        if k % 10 == 4:
            stream.append(packet(s)[:7] + b"\0")  # cut packet
            broken += 1
        if k % 10 == 7:
            stream.append(flipped(s, int(rng.integers(0, 13 * 8))))  # one bit flipped
            broken += 1
        if k % 25 == 9:
            stream.append(b"\x03\x01\x01\0")  # short body
            broken += 1
        if k % 33 == 0:
            stream.append(b"\0\0")  # idle fill: not an error
    blob = b"".join(stream)
    t_start = time.time()
    batches: list[SourceBatch] = []
    for at in range(0, len(blob), 997):  # pty buffers are small: write while reading
        os.write(master, blob[at : at + 997])
        batches.append(src.read(0.05))

    def complete(more: list[SourceBatch]) -> bool:
        seen = batches + more
        return n_frames(seen) >= len(samples) and sum(len(x.link_errors) for x in seen) >= broken

    batches += read_until(src, complete)
    src.close()
    frames = np.concatenate([b.frames for b in batches])
    errors = [e for b in batches for e in b.link_errors]
    got = records(frames)
    assert got == samples
    assert len(errors) == broken
    assert (frames["flags"] == FLAG_UART).all()
    assert ((frames["t"] >= t_start) & (frames["t"] <= time.time())).all()
    assert src.deframer.error_count == broken


def test_disconnect_when_master_closes(pty: tuple[int, str]) -> None:
    master, path = pty
    src = SerialSource(path, backoff_initial=0.01)
    os.write(master, packet(AdcSample(1, 0, 1, 0, 0)) + b"\x05\x01\x02")  # + a partial packet
    first = read_until(src, lambda b: n_frames(b) >= 1)
    assert n_frames(first) == 1
    os.close(master)
    batches = read_until(src, lambda b: any(n.kind == "disconnect" for x in b for n in x.notices))
    notices = [n for b in batches for n in b.notices]
    assert [n.kind for n in notices] == ["disconnect"]
    assert sum(len(b.link_errors) for b in batches) == 1  # the cut partial packet
    assert not src.connected
    for _ in range(3):  # keeps retrying the vanished pty quietly
        assert not src.read(0.02).notices
    assert not src.connected
    src.close()


def test_reconnect_through_a_stable_link(tmp_path: Path) -> None:
    """A USB adapter that re-enumerates: /dev/serial/by-id/... points at the new tty."""
    link = tmp_path / "ttyACB3"
    m1, s1 = os.openpty()
    tty.setraw(m1)
    link.symlink_to(os.ttyname(s1))
    os.close(s1)
    src = SerialSource(str(link), backoff_initial=0.01, backoff_max=0.05)
    m2 = s2 = -1
    try:
        os.write(m1, packet(AdcSample(1, 1, 1, 0, 1)))
        assert n_frames(read_until(src, lambda b: n_frames(b) >= 1)) == 1
        os.close(m1)
        m1 = -1
        gone = read_until(src, lambda b: any(n.kind == "disconnect" for x in b for n in x.notices))
        assert [n.kind for b in gone for n in b.notices] == ["disconnect"]
        m2, s2 = os.openpty()
        tty.setraw(m2)
        link.unlink()
        link.symlink_to(os.ttyname(s2))
        back = read_until(src, lambda b: any(n.kind == "reconnect" for x in b for n in x.notices))
        assert [n.kind for b in back for n in b.notices] == ["reconnect"]
        os.write(m2, packet(AdcSample(2, 2, 2, 0, 2)))
        frames = np.concatenate([b.frames for b in read_until(src, lambda b: n_frames(b) >= 1)])
        assert decode(int(frames["id"][0]), bytes(frames["data"][0])) == AdcSample(2, 2, 2, 0, 2)
    finally:
        src.close()
        for fd in (m1, m2, s2):
            if fd >= 0:
                os.close(fd)


def test_open_failure_is_one_line_bench_error(tmp_path: Path) -> None:
    with pytest.raises(BenchError) as e:
        SerialSource(str(tmp_path / "no-such-tty"))
    text = str(e.value)
    assert text.startswith(f"cannot open serial port {tmp_path / 'no-such-tty'} at {DEFAULT_BAUD}")
    assert "\n" not in text
