"""UART packet codec of the ACB-3 (ICD section 2): COBS-framed CAN frames with a CRC-16.

    packet = COBS(id_lo, id_hi, dlc, data[dlc], crc16_lo, crc16_hi) 0x00

Pure: bytes in, :class:`RawFrame` / :class:`LinkError` out, nothing raises for bad
bytes. A receiver may start mid-stream or meet line noise, so every decoder here
resynchronises at the next 0x00 and reports what it could not decode instead of
dropping it silently.

Receive time convention: a packet gets the ``t`` of the :meth:`Deframer.feed` call
that delivered its terminating 0x00 (that is when it became complete); a runaway
packet gets the ``t`` of the call in which it overran :data:`MAX_BODY`.
"""

from __future__ import annotations

import math

import numpy as np
from cobs import cobs

from protocol.crc import crc16_ccitt_false
from protocol.frames import FRAME_DTYPE, frames_from_raw
from protocol.layout import FRAME_DLC, Outcome
from protocol.records import FLAG_UART, LinkError, RawFrame

DELIMITER = b"\x00"
HEADER_LEN = 3
"""id_lo, id_hi, dlc."""
CRC_LEN = 2
MIN_PACKET = HEADER_LEN + CRC_LEN
"""Smallest decoded packet (dlc 0)."""
MAX_DLC = FRAME_DLC
"""The board only sends classical CAN frames (ICD 1: DLC 8), so we encode at most 8 bytes."""
MAX_BODY = 64
"""Longest COBS body accepted between delimiters. A dlc-8 packet is 14 bytes on the wire,
so anything longer than this is noise or a lost delimiter; bounding it keeps memory flat."""

_FULL_LEN = MIN_PACKET + FRAME_DLC  # decoded length of the usual dlc-8 packet


def _crc16_table() -> np.ndarray:
    """CRC-16/CCITT-FALSE byte table (poly 0x1021), for the vectorised check."""
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
        table.append(crc)
    return np.array(table, dtype=np.uint16)


_CRC16_NP = _crc16_table()


def _crc16_rows(rows: np.ndarray) -> np.ndarray:
    """crc16_ccitt_false of every row of an (N, k) uint8 array -> (N,) uint16."""
    crc = np.full(len(rows), 0xFFFF, dtype=np.uint16)
    for k in range(rows.shape[1]):
        crc = (crc << np.uint16(8)) ^ _CRC16_NP[(crc >> np.uint16(8)) ^ rows[:, k]]
    return crc


def encode_packet(can_id: int, data: bytes) -> bytes:
    """One UART packet for a CAN frame, trailing 0x00 included.

    Raises ValueError for an ID that does not fit 16 bits or more than 8 data bytes:
    those are programming errors of the sender (emulator), not wire conditions.
    """
    if not 0 <= can_id <= 0xFFFF:
        raise ValueError(f"can_id 0x{can_id:X} does not fit id_lo/id_hi")
    if len(data) > MAX_DLC:
        raise ValueError(f"{len(data)} data bytes, at most {MAX_DLC}")
    raw = bytes((can_id & 0xFF, can_id >> 8, len(data))) + bytes(data)
    crc = crc16_ccitt_false(raw)
    packet: bytes = cobs.encode(raw + bytes((crc & 0xFF, crc >> 8)))
    return packet + DELIMITER


def decode_packet(body: bytes, t: float) -> RawFrame | LinkError:
    """Decode the bytes between two delimiters. Checks in ICD order: COBS, length, CRC-16."""
    body = bytes(body)
    try:
        raw = cobs.decode(body)
    except cobs.DecodeError as exc:
        return _cobs_error(body, exc, t)
    if len(raw) < MIN_PACKET:
        return LinkError(t, Outcome.LENGTH_ERROR, body, f"{len(raw)} bytes, shorter than header")
    dlc = raw[2]
    if len(raw) != MIN_PACKET + dlc:
        return LinkError(
            t, Outcome.LENGTH_ERROR, body, f"{len(raw)} bytes, dlc {dlc} needs {MIN_PACKET + dlc}"
        )
    expected = crc16_ccitt_false(raw[: HEADER_LEN + dlc])
    got = raw[-2] | (raw[-1] << 8)
    if got != expected:
        return _crc_error(body, got, expected, t)
    return RawFrame(t, raw[0] | (raw[1] << 8), raw[HEADER_LEN : HEADER_LEN + dlc], FLAG_UART)


def _cobs_error(body: bytes, exc: Exception, t: float) -> LinkError:
    return LinkError(t, Outcome.COBS_ERROR, body, f"cobs: {exc}")


def _crc_error(body: bytes, got: int, expected: int, t: float) -> LinkError:
    return LinkError(t, Outcome.CRC16_ERROR, body, f"crc16 0x{got:04X}, expected 0x{expected:04X}")


def _runaway(body: bytes, t: float) -> LinkError:
    return LinkError(
        t, Outcome.LENGTH_ERROR, bytes(body[:MAX_BODY]), f"no delimiter within {MAX_BODY} bytes"
    )


def _unterminated(body: bytes, t: float) -> LinkError:
    return LinkError(
        t, Outcome.LENGTH_ERROR, bytes(body), f"unterminated packet ({len(body)} bytes)"
    )


def _segment(body: bytes, t: float) -> RawFrame | LinkError | None:
    """Outcome of one delimited body; None for an empty one (consecutive 0x00 are idle fill)."""
    if not body:
        return None
    if len(body) > MAX_BODY:
        return _runaway(body, t)
    return decode_packet(body, t)


class Deframer:
    """Streaming UART receiver: feed it chunks as they arrive, get frames and link errors.

    Holds at most :data:`MAX_BODY` bytes of a partial packet between feeds. Counters:
    ``ok`` (packets decoded), ``errors`` (link errors by Outcome), ``bytes_in``,
    ``discarded`` (bytes of runaway packets dropped after their error was reported).
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._discarding = False
        self._t = math.nan
        self.ok = 0
        self.errors: dict[Outcome, int] = {
            Outcome.COBS_ERROR: 0,
            Outcome.LENGTH_ERROR: 0,
            Outcome.CRC16_ERROR: 0,
        }
        self.bytes_in = 0
        self.discarded = 0

    @property
    def error_count(self) -> int:
        return sum(self.errors.values())

    @property
    def pending(self) -> int:
        """Bytes of a partial packet held for the next feed."""
        return len(self._buf)

    def _emit(
        self,
        result: RawFrame | LinkError | None,
        frames: list[RawFrame],
        errors: list[LinkError],
    ) -> None:
        if result is None:
            return
        if isinstance(result, LinkError):
            self.errors[result.outcome] += 1
            errors.append(result)
        else:
            self.ok += 1
            frames.append(result)

    def feed(self, chunk: bytes, t: float) -> tuple[list[RawFrame], list[LinkError]]:
        """Consume received bytes; return the packets completed (or overrun) by them."""
        frames: list[RawFrame] = []
        errors: list[LinkError] = []
        self._t = t
        chunk = bytes(chunk)
        self.bytes_in += len(chunk)
        *complete, rest = chunk.split(DELIMITER)
        for k, body in enumerate(complete):
            if k == 0:
                if self._discarding:  # end of a runaway: already reported
                    self._discarding = False
                    self.discarded += len(body)
                    continue
                body = bytes(self._buf) + body
                self._buf.clear()
            self._emit(_segment(body, t), frames, errors)
        self._absorb(rest, t, frames, errors)
        return frames, errors

    def _absorb(
        self, tail: bytes, t: float, frames: list[RawFrame], errors: list[LinkError]
    ) -> None:
        if self._discarding:
            self.discarded += len(tail)
            return
        if len(self._buf) + len(tail) > MAX_BODY:
            room = MAX_BODY - len(self._buf)
            self._emit(_runaway(bytes(self._buf) + tail[:room], t), frames, errors)
            self.discarded += len(self._buf) + len(tail)
            self._buf.clear()
            self._discarding = True
            return
        self._buf += tail

    def flush(self, t: float | None = None) -> tuple[list[RawFrame], list[LinkError]]:
        """End of stream: report a leftover partial packet (it never got its 0x00) and reset.

        ``t`` defaults to the time of the last feed.
        """
        errors: list[LinkError] = []
        if self._buf:
            self._emit(_unterminated(bytes(self._buf), self._t if t is None else t), [], errors)
        self._buf.clear()
        self._discarding = False
        return [], errors


def deframe_bytes(buf: bytes, t: float = math.nan) -> tuple[np.ndarray, list[LinkError]]:
    """Decode a whole capture into a FRAME_DTYPE array plus its link errors.

    Same result as feeding a fresh :class:`Deframer` any chunking of ``buf`` at time ``t``
    and flushing it, but vectorised: the CRC-16 of all dlc-8 packets is checked at once.
    """
    *bodies, tail = bytes(buf).split(DELIMITER)
    errors: list[tuple[int, LinkError]] = []
    slow: list[tuple[int, RawFrame]] = []
    fast_idx: list[int] = []
    fast_raw: list[bytes] = []
    fast_body: list[bytes] = []
    decode = cobs.decode
    for i, body in enumerate(bodies):
        if not body:
            continue
        if len(body) > MAX_BODY:
            errors.append((i, _runaway(body, t)))
            continue
        try:
            raw = decode(body)
        except cobs.DecodeError as exc:
            errors.append((i, _cobs_error(body, exc, t)))
            continue
        if len(raw) == _FULL_LEN and raw[2] == FRAME_DLC:
            fast_idx.append(i)
            fast_raw.append(raw)
            fast_body.append(body)
            continue
        result = decode_packet(body, t)
        if isinstance(result, LinkError):
            errors.append((i, result))
        else:
            slow.append((i, result))
    if tail:
        errors.append(
            (len(bodies), _runaway(tail, t) if len(tail) > MAX_BODY else _unterminated(tail, t))
        )

    rows = np.frombuffer(b"".join(fast_raw), dtype=np.uint8).reshape(-1, _FULL_LEN)
    got = rows[:, -2].astype(np.uint16) | (rows[:, -1].astype(np.uint16) << np.uint16(8))
    expected = _crc16_rows(rows[:, : HEADER_LEN + FRAME_DLC])
    good = expected == got
    for j in np.flatnonzero(~good):
        errors.append((fast_idx[j], _crc_error(fast_body[j], int(got[j]), int(expected[j]), t)))

    fast = np.zeros(int(good.sum()), dtype=FRAME_DTYPE)
    ok_rows = rows[good]
    fast["t"] = t
    fast["id"] = ok_rows[:, 0].astype(np.uint32) | (ok_rows[:, 1].astype(np.uint32) << 8)
    fast["dlc"] = FRAME_DLC
    fast["flags"] = FLAG_UART
    fast["data"] = ok_rows[:, HEADER_LEN : HEADER_LEN + FRAME_DLC]
    frames = np.concatenate([fast, frames_from_raw(f for _, f in slow)])
    order = np.concatenate(
        [np.asarray(fast_idx, dtype=np.int64)[good], np.array([i for i, _ in slow], dtype=np.int64)]
    )
    frames = frames[np.argsort(order, kind="stable")]
    errors.sort(key=lambda e: e[0])
    return frames, [e for _, e in errors]
