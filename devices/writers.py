"""Writers for frame arrays: candump ``.log`` (vectorised), python-can formats, raw UART captures.

:func:`write_candump` produces byte-for-byte what python-can's CanutilsLogWriter writes for
the same frames (via :func:`devices.bus.messages_from_frames`), including its quirks:
``%f`` timestamps (correctly rounded, half-even on exact ties), times earlier than the
first frame clamped to it, error frames as ``20000080#<data>`` without a direction, and
every frame marked received (`` R``). It is built with numpy column writes, so a million
frames take well under a second instead of several.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO, Any

import can
import numpy as np

from devices.bus import messages_from_frames, one_line
from devices.errors import BenchError
from protocol.records import FLAG_ERROR, FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE
from protocol.uart import encode_packet

_HEXUP = np.frombuffer(b"0123456789ABCDEF", dtype=np.uint8)
_SPLIT = 134217729.0  # 2**27 + 1, Veltkamp splitter
_MAX_FAST_T = 1e12
"""Beyond this (or negative, NaN, inf) a timestamp is formatted by Python, row by row."""
_ERR_ID = b"20000080"  # CAN_ERR_FLAG | CAN_ERR_BUSERROR, as python-can writes error frames


def _channel_text(channel: Any) -> bytes:
    if isinstance(channel, int) or (isinstance(channel, str) and channel.isdigit()):
        channel = f"can{channel}"
    return str(channel).encode()


def _micros(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact round-half-even of t * 1e6 to an integer, vectorised.

    Returns (k, fast): k is valid where fast; other rows (non-finite, negative, huge, or
    within float noise of a half-microsecond tie) must be formatted by Python.
    """
    with np.errstate(invalid="ignore", over="ignore"):
        fast = np.isfinite(t) & ~np.signbit(t) & (t < _MAX_FAST_T)
        tt = np.where(fast, t, 0.0)
        p = tt * 1e6
        # Dekker TwoProduct: p + e == tt * 1e6 exactly
        c = _SPLIT * tt
        th = c - (c - tt)
        tl = tt - th
        bh, bl = 1e6, 0.0  # 1e6 splits exactly
        e = ((th * bh - p) + th * bl + tl * bh) + tl * bl
        k = np.rint(p)
        s = (p - k) + e  # p - k is exact; |s| == 0.5 only near a tie
        k = k + (s > 0.5) - (s < -0.5)
        fast &= np.abs(s) != 0.5
    return k.astype(np.int64), fast


class CandumpWriter:
    """Streaming candump writer (open / write(frames) / close), same output as python-can's
    CanutilsLogWriter given the same frames in the same calls."""

    def __init__(
        self, path: str | os.PathLike[str], channel: Any = "can0", append: bool = False
    ) -> None:
        self.path = Path(path)
        self.channel = _channel_text(channel)
        self._first: float | None = None
        try:
            self._file: IO[bytes] | None = self.path.open("ab" if append else "wb")
        except OSError as exc:
            raise BenchError(f"cannot write {self.path}: {exc.strerror or exc}") from exc

    def __enter__(self) -> CandumpWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def write(self, frames: np.ndarray) -> None:
        if self._file is None:
            raise BenchError(f"cannot write {self.path}: writer is closed")
        if not len(frames):
            return
        if self._first is None:
            first = float(frames["t"][0])
            self._first = first if first else 0.0  # python-can: `msg.timestamp or 0.0`
        try:
            self._file.write(format_candump(frames, self.channel, self._first))
        except OSError as exc:
            raise BenchError(f"cannot write {self.path}: {exc.strerror or exc}") from exc

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def format_candump(
    frames: np.ndarray, channel: Any = "can0", first_t: float | None = None
) -> bytes:
    """Candump text of ``frames`` (bytes). ``first_t`` is the writer's first timestamp
    (earlier times are written as it); default: this array's first time."""
    n = len(frames)
    if not n:
        return b""
    chan = channel if isinstance(channel, bytes) else _channel_text(channel)
    t = frames["t"].astype(np.float64)
    if first_t is None:
        first_t = float(t[0]) or 0.0
    t = np.where(t < first_t, first_t, t)  # NaN compares false: kept, like python-can
    ids = frames["id"].astype(np.int64)
    dlc = frames["dlc"].astype(np.int64)
    flags = frames["flags"]
    data = np.ascontiguousarray(frames["data"])
    err = (flags & FLAG_ERROR) != 0
    remote = (flags & FLAG_REMOTE) != 0
    fd = ((flags & FLAG_FD) != 0) & ~remote
    ext = (flags & FLAG_EXTENDED) != 0
    nb = np.where(remote, 0, np.minimum(dlc, 8))

    # timestamp field "(S.UUUUUU)"
    k, fast = _micros(t)
    sec = k // 1_000_000
    usec = k % 1_000_000
    sw = np.ones(n, dtype=np.int64)
    for p in range(1, 13):
        sw += sec >= 10**p
    slow = np.flatnonzero(~fast)
    slow_text = [f"({v:f})".encode() for v in t[slow].tolist()]
    ts_len = sw + 9
    if len(slow):
        ts_len[slow] = [len(s) for s in slow_text]

    # id field: error frames print the error id, extended 8 hex digits, standard >= 3
    idw = np.full(n, 3, dtype=np.int64)
    for p in range(3, 8):
        idw += ids >= 16**p
    idw = np.where(ext | err, 8, idw)
    payload = np.where(remote, 1, np.where(fd, 2, 0) + 2 * nb)
    eol = np.where(err, 1, 3)
    length = ts_len + 1 + len(chan) + 1 + idw + 1 + payload + eol
    offs = np.cumsum(length) - length
    out = np.empty(int(length.sum()), dtype=np.uint8)

    def put(at: np.ndarray, value: np.ndarray | int) -> None:
        out[at] = value

    # timestamps, grouped by the width of the seconds
    for w in np.unique(sw[fast]).tolist():
        rows = np.flatnonzero(fast & (sw == w))
        o = offs[rows]
        s = sec[rows]
        put(o, ord("("))
        for j in range(w):
            put(o + 1 + j, 48 + (s // 10 ** (w - 1 - j)) % 10)
        put(o + 1 + w, ord("."))
        u = usec[rows]
        for j in range(6):
            put(o + 2 + w + j, 48 + (u // 10 ** (5 - j)) % 10)
        put(o + 8 + w, ord(")"))
    for r, text in zip(slow.tolist(), slow_text, strict=True):
        out[offs[r] : offs[r] + len(text)] = np.frombuffer(text, dtype=np.uint8)

    # " chan " id "#" payload eol, grouped by layout
    base = offs + ts_len
    key = (((idw * 2 + remote) * 2 + fd) * 16 + nb) * 2 + err
    chan_arr = np.frombuffer(b" " + chan + b" ", dtype=np.uint8)
    for kv in np.unique(key).tolist():
        rows = np.flatnonzero(key == kv)
        r0 = rows[0]
        o = base[rows]
        for j, byte in enumerate(chan_arr.tolist()):
            put(o + j, byte)
        o = o + len(chan_arr)
        w = int(idw[r0])
        if err[r0]:
            for j, byte in enumerate(_ERR_ID):
                put(o + j, byte)
        else:
            ident = ids[rows]
            for j in range(w):
                put(o + j, _HEXUP[(ident >> (4 * (w - 1 - j))) & 0xF])
        o = o + w
        put(o, ord("#"))
        o = o + 1
        if remote[r0]:
            put(o, ord("R"))
            o = o + 1
        else:
            if fd[r0]:
                put(o, ord("#"))
                put(o + 1, ord("0"))  # no BRS/ESI bits in FRAME_DTYPE
                o = o + 2
            for j in range(int(nb[r0])):
                byte = data[rows, j]
                put(o + 2 * j, _HEXUP[byte >> 4])
                put(o + 2 * j + 1, _HEXUP[byte & 0xF])
            o = o + 2 * int(nb[r0])
        if err[r0]:
            put(o, 10)
        else:
            put(o, 32)
            put(o + 1, ord("R"))
            put(o + 2, 10)
    return out.tobytes()


def write_candump(path: str | os.PathLike[str], frames: np.ndarray, channel: Any = "can0") -> None:
    """Write ``frames`` as a candump ``-L`` log, exactly as python-can's CanutilsLogWriter."""
    with CandumpWriter(path, channel) as writer:
        writer.write(frames)


def write_with_can_logger(path: str | os.PathLike[str], frames: np.ndarray, **kwargs: Any) -> None:
    """Write ``frames`` with python-can's own writer for the suffix (.asc/.blf/.trc/.csv/...)."""
    try:
        writer = can.Logger(os.fspath(path), **kwargs)
    except (ValueError, OSError) as exc:
        raise BenchError(f"cannot write {path}: {one_line(exc)}") from exc
    try:
        for msg in messages_from_frames(frames):
            writer.on_message_received(msg)
    except OSError as exc:
        raise BenchError(f"cannot write {path}: {one_line(exc)}") from exc
    finally:
        writer.stop()


def uart_bytes(frames: np.ndarray) -> bytes:
    """The UART byte stream the board would send for ``frames`` (ICD 2)."""
    dlc = frames["dlc"].tolist()
    rows = zip(frames["id"].tolist(), frames["data"].tolist(), dlc, strict=True)
    try:
        return b"".join(encode_packet(i, bytes(d[:n])) for i, d, n in rows)
    except ValueError as exc:
        raise BenchError(f"cannot encode UART packet: {one_line(exc)}") from exc


def write_uart_bin(path: str | os.PathLike[str], frames: np.ndarray) -> None:
    """Write a raw UART capture (.bin) of ``frames``."""
    payload = uart_bytes(frames)
    try:
        Path(path).write_bytes(payload)
    except OSError as exc:
        raise BenchError(f"cannot write {path}: {exc.strerror or exc}") from exc
