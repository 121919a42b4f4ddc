"""A recorded log put back onto a CAN bus at its recorded timing (``bench play``).

A HIL bench replays a recorded board's traffic into the unit that consumes it. python-can's
``can.player`` does that for the formats python-can reads; the bench reads more (its own
MCAP, candump text with its quirks, damaged files), so the frames come from the bench's
log opener (:func:`devices.formats.open_log`) and go through python-can's own pacing
(:class:`can.MessageSync`, the reference ``can.player`` uses) onto any python-can bus.

Play is on the caller's thread: a signal handler that raises (Ctrl-C, SIGTERM) stops it at
once, even in the middle of a long recorded gap. The counters are plain ints a status thread
may read at any time.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np

from bench.errors import BenchError
from bench.replay.prefetch import prefetch
from devices.bus import messages_from_frames, one_line
from devices.formats import open_log
from protocol.records import FLAG_ERROR

BATCH_FRAMES = 4096
"""Frames read at a time: a batch is read ahead while the previous one plays."""
SEND_TIMEOUT_S = 0.05


@dataclass(frozen=True)
class Selection:
    """Which of the log's frames go onto the bus."""

    ids: frozenset[int] | None = None  # None: every ID
    skip_to_s: float = 0.0  # seconds after the log's first frame
    # error frames are never sent (can.player's default): a bus makes its own


@dataclass
class LogCounts:
    """What a first pass over the log found."""

    in_log: int = 0  # every frame the log holds
    selected: int = 0  # those the selection puts on the bus
    by_ids: int = 0  # left out by --ids
    before_skip: int = 0  # left out by --skip-to
    error_frames: int = 0  # error frames (selected otherwise), not sent
    problems: int = 0  # unreadable lines, link errors, a truncated end: reported, not sent
    t0: float = math.nan  # the log's first receive time
    t_end: float = math.nan  # its last

    @property
    def duration_s(self) -> float:
        return self.t_end - self.t0 if math.isfinite(self.t0) else 0.0


def _batches(path: Path) -> Iterator[Any]:
    source = open_log(path)
    try:
        yield from source.batches(BATCH_FRAMES)
    finally:
        source.close()


def count_log(path: Path, selection: Selection) -> LogCounts:
    """Count the log's frames and what the selection keeps; a log without receive times
    (a raw UART capture) cannot be paced and is refused."""
    c = LogCounts()
    for batch in _batches(path):
        c.problems += len(batch.link_errors) + sum(
            n.kind in ("parse_error", "truncated") for n in batch.notices
        )
        f = batch.frames
        if not len(f):
            continue
        if not np.isfinite(f["t"]).all():
            raise BenchError(
                f"{path}: its frames have no receive times (a raw UART capture?): "
                "nothing to play them at their recorded timing by"
            )
        if c.in_log == 0:
            c.t0 = float(f["t"][0])
        c.t_end = float(np.fmax(c.t_end, f["t"].max()))  # fmax: the NaN of "none yet" yields
        c.in_log += len(f)
        late, wanted, error = _masks(f, c.t0, selection)
        c.before_skip += int((~late).sum())
        c.by_ids += int((late & ~wanted).sum())
        c.error_frames += int((late & wanted & error).sum())
        c.selected += int((late & wanted & ~error).sum())
    return c


def _masks(
    frames: np.ndarray, t0: float, selection: Selection
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(at or after --skip-to, of a wanted ID, an error frame) per frame."""
    late = frames["t"] - t0 >= selection.skip_to_s
    ids = selection.ids
    wanted = np.isin(frames["id"], list(ids)) if ids is not None else np.ones(len(frames), bool)
    return late, wanted, (frames["flags"] & FLAG_ERROR) != 0


def _keep(frames: np.ndarray, t0: float, selection: Selection) -> np.ndarray:
    late, wanted, error = _masks(frames, t0, selection)
    return late & wanted & ~error


class BusPlayer:
    """Plays the selected frames of one log onto ``bus``, ``rate`` times as fast as recorded,
    once or (``loop``) until stopped. Send errors are counted and play goes on; a frame that
    failed is not retried."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        bus: can.BusABC,
        counts: LogCounts,
        selection: Selection = Selection(),
        *,
        rate: float = 1.0,
        loop: bool = False,
    ) -> None:
        self.path = Path(path)
        self.bus = bus
        self.counts = counts
        self.selection = selection
        self.rate = rate
        self.loop = loop
        self.passes = 0  # passes begun
        self.sent = 0
        self.errors = 0
        self.last_error = ""
        self.position_s = 0.0  # log time of the last frame handed to the bus, from the start
        # set by a signal handler besides raising it: a raise that lands in a finaliser is
        # swallowed by Python, and play would go on to the end (or for ever with loop)
        self.interrupt: BaseException | None = None

    def play(self) -> None:
        """Until the log (each pass of it, with ``loop``) has been played."""
        while True:
            self.passes += 1
            self._one_pass()
            if not self.loop or not self.counts.selected:
                return

    def _message_lists(self) -> Iterator[list[can.Message]]:
        """The selected frames as python-can Messages, a batch at a time, stamped with their
        time from the log's start divided by the rate (what MessageSync paces by)."""
        t0, rate = self.counts.t0, self.rate
        for batch in _batches(self.path):
            f = batch.frames
            if not len(f):
                continue
            f = f[_keep(f, t0, self.selection)]
            msgs = messages_from_frames(f)
            for msg, t in zip(msgs, ((f["t"] - t0) / rate).tolist(), strict=True):
                msg.timestamp = t
            yield msgs

    def _one_pass(self) -> None:
        # reading and building Messages run ahead in a thread of their own, so that the
        # playing thread only waits on the recorded timing
        messages = itertools.chain.from_iterable(prefetch(self._message_lists()))
        first = next(messages, None)
        if first is None:
            return
        send = self.bus.send
        rate = self.rate
        # MessageSync starts its clock when it starts: with the first message in hand, not
        # before the first read (which would send the first frames late, then in a burst)
        for msg in can.MessageSync(itertools.chain([first], messages), timestamps=True, skip=0):
            if self.interrupt is not None:
                raise self.interrupt
            self.position_s = msg.timestamp * rate
            try:
                send(msg, timeout=SEND_TIMEOUT_S)
                self.sent += 1
            except (can.CanError, OSError) as exc:
                self.errors += 1
                self.last_error = one_line(exc)


def parse_ids(text: str) -> frozenset[int]:
    """``--ids``: CAN IDs in hex as candump prints them (``101``, ``0x101``), comma-separated,
    ``100-10F`` for a range."""
    ids: set[int] = set()
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        lo_text, _, hi_text = part.partition("-")
        try:
            lo = int(lo_text, 16)
            hi = int(hi_text, 16) if hi_text else lo
        except ValueError:
            raise ValueError(f"{part!r} is not a hex CAN ID (e.g. 101 or 0x101)") from None
        if not (0 <= lo <= hi <= 0x1FFFFFFF):
            raise ValueError(f"{part!r} is not a CAN ID range within 0..1FFFFFFF")
        if hi - lo > 0x7FF:
            raise ValueError(f"{part!r} spans more than 2048 IDs")
        ids.update(range(lo, hi + 1))
    if not ids:
        raise ValueError("no CAN ID given")
    return frozenset(ids)
