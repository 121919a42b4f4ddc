"""Where each valid ADC frame goes on the sample axis: board ticks and counter first.

The board's 16-bit timestamp (100 us ticks, wraps every 6.5536 s) and its 8-bit counter
place a frame relative to the ADC frame placed before it. Only a gap longer than half a
timestamp wrap needs the host's receive clock, and that clock is the least trustworthy of
the three: it can step (NTP, a suspended laptop, a log spliced from two captures) and one
frame can carry a wild stamp. So receive time is checked against board time, frame by
frame, through the *receive offset* ``t - ticks * TICK_S``, which is constant on a healthy
stream (up to host jitter and clock drift):

* A frame whose offset agrees with the reference (the last frame that agreed) to within
  RX_TOLERANCE_S is normal; almost every frame passes that test in one comparison with
  its predecessor (the vectorised fast check).
* A frame that disagrees is *suspect*. If its board ticks keep it within WINDOW samples
  of the stream it is placed (its receive time is the odd one; the sample gets the time
  board ticks predict) and the next frame tells a lone receive-time outlier
  (TIME_OUTLIER) from a clock step (CLOCK_STEP, a notice; the new offset is the
  reference from then on). If its board ticks throw it further than that, its board time
  is the odd one: it is dropped as an OUTLIER, and only if the next frame agrees with it
  (the board clock really jumped) does the stream follow it (CLOCK_STEP).
* Timestamp wraps are bridged by receive time (:func:`gap_wraps`): a gap that is a whole
  number of wraps to within BRIDGE_TOLERANCE_S (plus 100 ppm of the gap) bridges them. A
  real gap whose receive delay changed (a link down/up) is further off, and so is a host
  clock step without a gap: the sample counter picks between the two nearest wrap counts.
  If it cannot tell, the nearest within GUESS_TOLERANCE_S is taken, a WRAP_GUESS notice.
  A clock step of almost exactly k * 6.5536 s stays indistinguishable from a gap.

The assembler calls :meth:`Timeline.slow` for every frame the fast check does not pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.records.events import EventKind
from bench.records.samples import MAX_BRIDGE_TICKS
from protocol.layout import COUNTER_WRAP, TICK_S, TS_WRAP

WINDOW = 2
"""Samples a sample may wait for its missing channels ("about two sample periods")."""

RX_TOLERANCE_S = 1.0
"""Receive offset change beyond which a frame's receive time disagrees with its board time
(host jitter, a stalled sender and clock drift stay far below it)."""
RX_TOL_TICKS = RX_TOLERANCE_S / TICK_S
BRIDGE_TOLERANCE_S = 0.2
"""How far a receive-time gap may be from whole timestamp wraps and still be bridged."""
BRIDGE_TOL_TICKS = BRIDGE_TOLERANCE_S / TICK_S
BRIDGE_PPM = 1e-4
"""Relative clock drift allowed on top of BRIDGE_TOLERANCE_S over a long gap."""
GUESS_TOLERANCE_S = 2.0
"""How far (about 0.3 of a wrap) a receive-time gap may be from whole wraps and still be
bridged to the nearest whole number when the counter cannot tell (a WRAP_GUESS notice)."""
GUESS_TOL_TICKS = GUESS_TOLERANCE_S / TICK_S
COUNTER_SLACK = 1
"""Samples the counter may disagree with a candidate step (period estimate, rounding)."""
COUNTER_SPAN = 500_000
"""Samples across which the counter still tells wraps apart (a period off by 1 ppm stays
under half a sample); past that only the receive clock counts them."""

HALF_CW = COUNTER_WRAP // 2
HALF_TS = TS_WRAP // 2
_OUTLIER, _TIME_OUTLIER, _CLOCK_STEP, _WRAP_GUESS = (
    int(EventKind.OUTLIER),
    int(EventKind.TIME_OUTLIER),
    int(EventKind.CLOCK_STEP),
    int(EventKind.WRAP_GUESS),
)
_MS_LIMIT = float(2**62)

Chain = tuple[float, int, int, int, int]
"""t, ts, T (unwrapped ticks), counter, n of the ADC frame placed last."""
Note = tuple[float, int, int, int, int]
"""An event the timeline raised: (t, kind, channel, n, value), EVENT_DTYPE order."""


def ms(seconds: float) -> int:
    """Whole milliseconds for an event value, clamped (a 1e300 s stamp must not raise)."""
    value = seconds * 1000.0
    if math.isnan(value):
        return 0
    return round(max(-_MS_LIMIT, min(_MS_LIMIT, value)))


def board_step(d: int, c: int, c0: int, period: float, known: bool) -> int:
    """Sample-index step for a board-time step of ``d`` ticks (one frame of
    :func:`vector_steps`): board time alone once the rate is known, else the counter corrects it."""
    est = round(d / period)  # round half even, like np.rint
    if known:
        return est
    return est + (c - c0 - est + HALF_CW) % COUNTER_WRAP - HALF_CW


def counter_fits(big_d: float, dc: int, period: float) -> bool:
    """Whether a board-time step of ``big_d`` ticks agrees with a counter step ``dc``."""
    miss = (dc - round(big_d / period) + HALF_CW) % COUNTER_WRAP - HALF_CW
    return abs(miss) <= COUNTER_SLACK


def gap_wraps(elapsed: float, d: int, dc: int, period: float) -> tuple[int, bool]:
    """Whole timestamp wraps hidden in a step, and whether that is a guess.

    ``elapsed`` is the step the receive clock measures (ticks, NaN for raw captures), ``d``
    the centred timestamp step, ``dc`` the counter step. A receive-time gap within
    BRIDGE_TOLERANCE_S of whole wraps bridges them. Further off (the receive delay changed
    across the gap, or the host clock stepped), the candidates are the two wrap counts
    nearest the receive time and zero (a clock step without a gap), and the counter picks
    the one it agrees with. If it agrees with several, or with none, the nearest is taken
    within GUESS_TOLERANCE_S and reported as a guess; otherwise none (the frame is then
    judged by its offsets, as a clock step or an outlier). Over a gap too long for the
    counter, only the first rule bridges.
    """
    gap = elapsed - d
    if not (math.isfinite(gap) and abs(elapsed) <= MAX_BRIDGE_TICKS):
        return 0, False
    near = round(gap / TS_WRAP)
    miss = gap - near * TS_WRAP
    if near > 0 and abs(miss) <= BRIDGE_TOL_TICKS + BRIDGE_PPM * abs(elapsed):
        return near, False
    other = near + (1 if miss > 0 else -1)
    counts = period > 0 and abs(elapsed) < period * COUNTER_SPAN  # False for a NaN period
    if max(near, other) <= 0 or not counts:
        return 0, False
    fits = {k for k in (near, other, 0) if k >= 0 and counter_fits(d + k * TS_WRAP, dc, period)}
    if len(fits) == 1:
        return fits.pop(), False
    if near > 0 and abs(miss) <= GUESS_TOL_TICKS:
        return near, True
    return 0, False


def vector_steps(
    d: np.ndarray,
    c: np.ndarray,
    c_prev: np.ndarray,
    period: float | np.ndarray,
    known: bool | np.ndarray,
) -> np.ndarray:
    """:func:`board_step` over arrays (each frame against its predecessor)."""
    est = np.rint(d / period).astype(np.int64)
    if known is True:
        return est
    dc = (c - c_prev - est.astype(np.uint8)).view(np.int8)
    return est + dc if known is False else np.where(known, est, est + dc)


@dataclass(slots=True)
class Pending:
    """A suspect frame the next one decides about."""

    placed: bool  # True: receive time was the odd one, False: dropped as an OUTLIER
    t_event: float  # the receive time its board time predicts
    channel: int
    n: int
    off: float  # its receive offset
    dev: float  # its offset minus the reference's, s
    chain: Chain  # where it sits (for a dropped one: where it would have)


class Timeline:
    """State of frame placement between batches (small Python values)."""

    def __init__(self) -> None:
        self.chain: Chain | None = None
        self.ref: tuple[float, int] | None = None  # (t, T) of the reference; None: the chain
        self.pending: Pending | None = None
        self.notes: list[Note] = []

    def start(self, t: float, ts: int, c: int) -> None:
        """The first ADC frame opens the chain at its own counter and ticks."""
        self.chain = (t, ts, ts, c, c)

    def reference_offset(self) -> float:
        assert self.chain is not None
        t, big_t = self.ref if self.ref is not None else (self.chain[0], self.chain[2])
        return t - big_t * TICK_S

    def take_notes(self) -> list[Note]:
        notes, self.notes = self.notes, []
        return notes

    def finish(self) -> list[Note]:
        """End of stream: a suspect frame nothing came after is taken for a lone one."""
        p, self.pending = self.pending, None
        if p is not None and p.placed:
            self.notes.append((p.t_event, _TIME_OUTLIER, p.channel, p.n, ms(p.dev)))
        return self.take_notes()

    @staticmethod
    def _ticks(
        t: float, ts: int, c: int, chain: Chain, ref_off: float, period: float
    ) -> tuple[int, int]:
        """Unwrapped board time of a frame after ``chain``, and the wraps it bridged on a
        guess (0: none). The centred timestamp step, plus the whole wraps a receive-time
        gap (against ``ref_off``) asks for: see :func:`gap_wraps`."""
        ts0, big_t0 = chain[1], chain[2]
        d = (ts - ts0 + HALF_TS) % TS_WRAP - HALF_TS
        pred = (t - ref_off) / TICK_S  # board ticks the receive time predicts
        wraps, guessed = gap_wraps(pred - big_t0, d, c - chain[3], period)
        return big_t0 + d + TS_WRAP * wraps, wraps if guessed else 0

    def _judge(
        self,
        t: float,
        ts: int,
        c: int,
        chain: Chain,
        ref_off: float,
        period: float,
        known: bool,
        max_n: int,
    ) -> tuple[int, int, float, float, bool, bool, int]:
        """A frame placed after ``chain``: (T, n, receive offset, its change against
        ``ref_off``, receive time disagrees, board time throws it ahead against its counter,
        timestamp wraps bridged on a guess)."""
        big_t, guess = self._ticks(t, ts, c, chain, ref_off, period)
        step = board_step(big_t - chain[2], c, chain[3], period, known)
        off = t - big_t * TICK_S
        dev = off - ref_off
        suspect = math.isfinite(ref_off) and not abs(dev) <= RX_TOLERANCE_S
        jump = chain[4] + step > max_n + WINDOW and (c - chain[3] - step) % COUNTER_WRAP != 0
        return big_t, chain[4] + step, off, dev, suspect, jump, guess

    def slow(
        self, t: float, ts: int, c: int, ch: int, period: float, known: bool, max_n: int
    ) -> tuple[int, int, float] | None:
        """Place a frame the fast check did not pass: (n, T, receive time for the sample),
        or None when it is dropped as an outlier. Raises the timeline's events."""
        chain = self.chain
        assert chain is not None
        ref_off = self.reference_offset()
        p, self.pending = self.pending, None
        big_t, n, off, dev, suspect, jump, guess = self._judge(
            t, ts, c, chain, ref_off, period, known, max_n
        )
        if (suspect or jump) and p is not None:
            if p.placed and suspect and abs(off - p.off) <= RX_TOLERANCE_S:
                self.notes.append((p.t_event, _CLOCK_STEP, 0, -1, ms(p.dev)))  # receive clock
                return self._settle(t, ts, c, ch, big_t, n, guess)
            if not p.placed:
                t2, n2, _, _, s2, j2, g2 = self._judge(t, ts, c, p.chain, p.off, period, known, p.n)
                if not (s2 or j2):  # it agrees with the dropped frame: the board clock jumped
                    self.notes.append((p.t_event, _CLOCK_STEP, 0, -1, ms(p.dev)))
                    return self._settle(t, ts, c, ch, t2, n2, g2)
        if p is not None and p.placed:
            self.notes.append((p.t_event, _TIME_OUTLIER, p.channel, p.n, ms(p.dev)))
        if not (suspect or jump):
            return self._settle(t, ts, c, ch, big_t, n, guess)
        t_board = ref_off + big_t * TICK_S  # the receive time its board time predicts
        if not math.isfinite(t_board):
            t_board = chain[0]
        if self.ref is None:
            self.ref = (chain[0], chain[2])
        here: Chain = (t, ts, big_t, c, n)
        if not jump and max_n - WINDOW <= n <= max_n + WINDOW:
            self.pending = Pending(True, t_board, ch, n, off, dev, here)
            self.chain = here
            if guess:
                self.notes.append((t_board, _WRAP_GUESS, ch, n, guess))
            return n, big_t, t_board
        self.notes.append((t_board, _OUTLIER, ch, n, ms(dev)))
        self.pending = Pending(False, t_board, ch, n, off, dev, here)
        return None

    def _settle(
        self, t: float, ts: int, c: int, ch: int, big_t: int, n: int, guess: int
    ) -> tuple[int, int, float]:
        """Place a frame that agrees with the reference (now itself)."""
        if guess:
            self.notes.append((t, _WRAP_GUESS, ch, n, guess))
        self.chain = (t, ts, big_t, c, n)
        self.ref = None
        return n, big_t, t
