"""Typed events: everything the bench notices that is not a result (faults, link errors, marks).

Events travel as a numpy structured array so a log with a million CRC errors costs no
Python objects; :func:`describe` renders one for people (TUI, MCAP log messages).
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class EventKind(IntEnum):
    CRC_ERROR = 1  # channel = ADC channel or 0; value = frame id
    WRONG_DLC = 2  # value = dlc
    UNKNOWN_ID = 3  # value = frame id
    DUPLICATE = 4  # channel, n
    LATE = 5  # channel, n: arrived after its sample was closed
    GAP = 6  # channel, n: sample closed without that channel
    SAMPLES_LOST = 7  # n = first missing sample, value = how many
    COUNTER_JUMP = 8  # channel, n; value = jump size (counter vs board timestamp)
    STATUS_FLAG = 9  # channel, n; value = status byte
    LINK_ERROR = 10  # value = protocol.layout.Outcome of the UART packet
    PARSE_ERROR = 11  # a log line or record that could not be read
    DISCONNECT = 12
    RECONNECT = 13
    MARK = 14  # operator mark
    VOTE_FAIL = 15  # n; value = bitmask of failed votes (1=v1, 2=v2, 4=v3) when any fails
    INVALID = 16  # n: all three votes failed, no reference gradient
    EXCLUDED = 17  # channel, n: the estimator excluded a channel; value = reason code
    READMITTED = 18  # channel, n: the estimator readmitted it
    BOARD_STATE = 19  # value = new board state
    # 20: unused (kinds are recorded in logs by number: never renumber)
    DROPPED = 21  # value = frames dropped by a full queue
    OUTPUT_ERROR = 22  # a secondary output (CSV) failed; value = errno (28: disk full), or 0
    OUTLIER = 23  # channel, n: a lone frame whose board time threw it off the stream (dropped);
    # value = its receive-minus-board time against the stream's, ms
    TIME_OUTLIER = 24  # channel, n: a lone frame whose receive time was off (frame used); value ms
    CLOCK_STEP = 25  # receive time minus board time stepped (host or board clock); value = ms
    SOCKET_OVERFLOW = 26  # value = frames the kernel dropped at a full socket receive buffer
    WRAP_GUESS = 27  # channel, n: a long gap's timestamp wraps taken from the receive clock alone,
    # the counter could not confirm them; value = wraps bridged
    MODEL_DROPPED = 28  # value = samples the live model's full queue dropped (--lag): its
    # /bench/model rows from then on are no longer what a replay of the log gives


EVENT_DTYPE = np.dtype(
    [("t", "<f8"), ("kind", "u1"), ("channel", "u1"), ("n", "<i8"), ("value", "<i8")]
)

SEVERITY = {
    EventKind.MARK: "info",
    EventKind.RECONNECT: "info",
    EventKind.READMITTED: "info",
    EventKind.BOARD_STATE: "info",
    EventKind.DUPLICATE: "warning",
    EventKind.LATE: "warning",
    EventKind.GAP: "warning",
    EventKind.VOTE_FAIL: "warning",
    EventKind.STATUS_FLAG: "warning",
    EventKind.UNKNOWN_ID: "info",
    EventKind.OUTLIER: "warning",
    EventKind.TIME_OUTLIER: "warning",
    EventKind.CLOCK_STEP: "info",
    EventKind.WRAP_GUESS: "info",
    EventKind.MODEL_DROPPED: "warning",
}


NO_EVENTS = np.zeros(0, dtype=EVENT_DTYPE)
"""The shared empty event array (zero-length: nothing in it can be written)."""


def make_events(
    kind: EventKind | int,
    t: np.ndarray | float,
    channel: np.ndarray | int = 0,
    n: np.ndarray | int = -1,
    value: np.ndarray | int = 0,
) -> np.ndarray:
    """Events of one kind, broadcast over the array arguments."""
    if isinstance(t, np.ndarray) and t.ndim == 1:
        rest = (channel, n, value)
        if all(np.ndim(x) == 0 or np.shape(x) == t.shape for x in rest):
            # the usual call (columns of one length, or scalars): fill the fields directly
            out = np.empty(len(t), dtype=EVENT_DTYPE)  # every field is written below
            out["t"] = t
            out["kind"] = int(kind)
            # (0-d arrays cast like the broadcast path: an out-of-range int wraps, not raises)
            out["channel"] = np.asarray(channel)
            out["n"] = np.asarray(n)
            out["value"] = np.asarray(value)
            return out
    t_arr, ch, nn, val = np.broadcast_arrays(
        np.asarray(t, dtype=np.float64), np.asarray(channel), np.asarray(n), np.asarray(value)
    )
    out = np.zeros(t_arr.shape, dtype=EVENT_DTYPE).ravel()
    out["t"] = t_arr.ravel()
    out["kind"] = int(kind)
    out["channel"] = ch.ravel()
    out["n"] = nn.ravel()
    out["value"] = val.ravel()
    return out


def _in_order(t: np.ndarray) -> bool:
    """Non-decreasing (False with any NaN, which the stable sort puts last)."""
    return bool(np.all(t[1:] >= t[:-1]))


_WORD = np.uint16 if EVENT_DTYPE.itemsize % 2 == 0 else np.uint8


def _words(events: np.ndarray) -> np.ndarray:
    """(N, k) plain-integer view of contiguous events: rows move as memory blocks, several
    times faster than numpy's field-by-field copy of structured elements."""
    return events.view(_WORD).reshape(len(events), -1)


def _merge(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Stable merge of two time-ordered event arrays: each of b's events goes after every
    event of a at the same time."""
    if a["t"][-1] <= b["t"][0]:
        return np.concatenate((a, b))
    at_b = np.searchsorted(a["t"], b["t"], side="right") + np.arange(len(b))
    out = np.empty(len(a) + len(b), dtype=EVENT_DTYPE)  # every row is written below
    from_a = np.ones(len(out), dtype=bool)
    from_a[at_b] = False
    rows = _words(out)
    rows[at_b] = _words(np.ascontiguousarray(b))
    rows[from_a] = _words(np.ascontiguousarray(a))
    return out


def concat_events(parts: list[np.ndarray]) -> np.ndarray:
    """The parts as one array in time order: the stable sort by ``t`` of their
    concatenation (equal times keep part order, NaN last); a single part as it is. Parts
    already in order (the usual case) are merged in linear time instead of sorted."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return NO_EVENTS
    if len(parts) == 1:
        return parts[0]
    if all(_in_order(p["t"]) for p in parts):
        out = parts[0]
        for part in parts[1:]:
            out = _merge(out, part)
        return out
    out = np.concatenate(parts)
    order = np.argsort(out["t"], kind="stable")
    return _words(out)[order].view(EVENT_DTYPE).reshape(len(out))


def severity(kind: int) -> str:
    return SEVERITY.get(EventKind(kind), "error")


def describe(ev: np.void | np.ndarray) -> str:
    """One line for a person: 'GAP ch3 sample 1234'."""
    kind = EventKind(int(ev["kind"]))
    ch = int(ev["channel"])
    n = int(ev["n"])
    value = int(ev["value"])
    parts = [kind.name]
    if ch:
        parts.append(f"ch{ch}")
    if n >= 0:
        parts.append(f"sample {n}")
    if kind in (EventKind.CRC_ERROR, EventKind.UNKNOWN_ID):
        parts.append(f"id 0x{value:03X}")
    elif kind is EventKind.STATUS_FLAG:
        from protocol.layout import status_names

        parts.append("status " + "|".join(status_names(value)))
    elif kind is EventKind.VOTE_FAIL:
        parts.append("failed " + ",".join(f"v{i + 1}" for i in range(3) if value & (1 << i)))
    elif kind is EventKind.SOCKET_OVERFLOW:
        parts.append(f"{value} frames dropped by the kernel (socket receive buffer full)")
    elif kind in (EventKind.OUTLIER, EventKind.TIME_OUTLIER, EventKind.CLOCK_STEP):
        parts.append(f"{value / 1000:+.3f} s")
    elif kind is EventKind.MODEL_DROPPED:
        parts.append(f"{value} samples dropped by the live model's full queue")
    elif kind is EventKind.WRAP_GUESS:
        parts.append(f"{value} timestamp wraps assumed across a gap (receive clock)")
    elif kind is EventKind.OUTPUT_ERROR:
        import os

        parts.append(os.strerror(value) if value > 0 else "write failed")
    elif kind is EventKind.LINK_ERROR:
        from protocol.layout import Outcome

        parts.append(Outcome(value).name if value in Outcome._value2member_map_ else str(value))
    elif value:
        parts.append(f"value {value}")
    return " ".join(parts)
