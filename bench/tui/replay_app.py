"""The TUI on a replayed log: play/pause, speed, step, run to the next event of a kind,
back 10 s, and start again.

Seeking back is a restart plus a run at full speed to the log time wanted: fusion and the
estimator carry state from sample to sample, so the only exact way to show sample N again
is to compute everything before it again (a 10-minute log at 200 Hz takes a few seconds).
The restart builds a new Session on the same file (the ``restart`` factory the command
passes) and swaps it in; the panels start empty.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Sequence
from typing import Any, ClassVar

from textual import work
from textual.app import SystemCommand
from textual.binding import Binding, BindingType
from textual.screen import Screen

from bench.records.events import EventKind
from bench.replay.player import SEEK_TARGETS
from bench.tui.app import BenchApp
from bench.tui.panels.channels import RateMeter
from bench.tui.panels.events import EventsPanel

BACK_S = 10.0
"""How far ``b`` goes back (log time)."""

RestartFactory = Callable[[bool], Any]
"""Builds a new replay Session on the same log (argument: start paused), not started."""


class ReplayApp(BenchApp):
    """:class:`BenchApp` plus the replay keys. Recording, marks and the tolerance keys still
    work but leave the footer to the replay keys (``?`` lists them all)."""

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("p", "pause_display", "Pause display", show=False),
        Binding("r", "record", "Rec", show=False),
        Binding("m", "mark", "Mark", show=False),
        Binding("plus,equals_sign", "tolerance(1)", "Tol+", key_display="+", show=False),
        Binding("minus", "tolerance(-1)", "Tol-", key_display="-", show=False),
        Binding("space", "play_pause", "Play", key_display="spc"),
        Binding("s", "speed", "Speed"),
        Binding("n", "step", "Step"),
        Binding("j", "next_failure", "Next"),
        Binding("t", "seek_target", "Target"),
        Binding("b", "seek_back", "Back"),
        Binding("0,home", "restart", "Restart", key_display="0", show=False),
    ]

    def __init__(
        self,
        session: Any,
        *,
        restart: RestartFactory | None = None,
        recorded_marks: Sequence[tuple[float, str]] = (),
        **kwargs: Any,
    ) -> None:
        super().__init__(session, **kwargs)
        self.restart = restart
        self.recorded_marks = sorted(recorded_marks)
        self.target = 0  # index into SEEK_TARGETS
        self.restarts = 0
        self.back_s = BACK_S
        self._restarting = False

    # -- what j runs to -----------------------------------------------------------------
    def action_seek_target(self) -> None:
        """Cycle what ``j`` runs to: vote failure, INVALID, exclusion, fault, mark."""
        self.target = (self.target + 1) % len(SEEK_TARGETS)
        self.seek_label = SEEK_TARGETS[self.target][0]
        self.notify(f"j runs to the next {self.seek_label}")
        self._update_status_bar()

    def action_next_failure(self) -> None:
        """Run to the next event of the chosen kind (``t``), pause there, show it."""
        replay = self.session.replay
        if replay is None:
            return
        label, kinds = SEEK_TARGETS[self.target]
        self.seek_label = label
        if EventKind.MARK in kinds:
            t = self._next_mark_time()
            if t is None:  # the sample shown stays shown
                self.notify("no recorded mark after this point", severity="warning")
                return
            self.cursor_n = None
            replay.seek_time(t)
        else:
            self.cursor_n = None
            replay.seek_event(kinds)
        self._update_status_bar()

    def _position(self) -> float:
        """The log time of the sample shown (the cursor's, else the newest)."""
        row = self._row(self.last_snapshot) if self.last_snapshot is not None else None
        return float(row["t"]) if row is not None else -math.inf

    def _next_mark_time(self) -> float | None:
        times = [t for t, _ in self.recorded_marks]
        i = bisect.bisect_right(times, self._position() + 1e-6)
        return times[i] if i < len(times) else None

    # -- back and restart -----------------------------------------------------------------
    def action_seek_back(self) -> None:
        """Show the sample ``BACK_S`` of log time before the one shown."""
        pos = self._position()
        if not math.isfinite(pos):
            return
        self.seek_label = f"{self.back_s:g} s back"
        self._restart(pos - self.back_s)

    def action_restart(self) -> None:
        """Play the log again from its first frame."""
        self.seek_label = "start"
        self._restart(None)

    def _restart(self, seek_to: float | None) -> None:
        if self.restart is None:
            self.notify("this replay cannot be restarted", severity="warning")
            return
        if self._restarting or self.quitting:
            return
        self._restarting = True
        self._swap(seek_to)

    @work(thread=True, group="restart", exit_on_error=False)
    def _swap(self, seek_to: float | None) -> None:
        """Stop the current session (its recording, if any, is finished), build and start
        a new one on the same log, then show it."""
        old = self.session
        try:
            old.stop()
            assert self.restart is not None
            new = self.restart(seek_to is not None)
            new.start()
            if seek_to is not None and new.replay is not None:
                new.replay.seek_time(seek_to)
        except Exception as exc:
            self._restarting = False
            self.call_from_thread(self.notify, f"restart failed: {exc!r}", severity="error")
            return
        self.call_from_thread(self._swapped, new)

    def _swapped(self, new: Any) -> None:
        self.session = new
        self.restarts += 1
        self.cursor_n = None
        self.last_snapshot = None
        self._failure_seen = None
        self._rates = RateMeter()
        self.query_one(EventsPanel).reset()
        self.plot_pacer.force()
        self._restarting = False
        self._polling = False
        self._update_status_bar()
        self.poll()

    # -- palette --------------------------------------------------------------------------
    def get_system_commands(self, screen: Screen) -> Any:
        yield from super().get_system_commands(screen)
        yield SystemCommand("Play/pause replay", "(space)", self.action_play_pause)
        yield SystemCommand("Replay speed", "Cycle 1x / 10x / max (s)", self.action_speed)
        yield SystemCommand("Step", "One sample on (n)", self.action_step)
        for k, (label, _) in enumerate(SEEK_TARGETS):
            yield SystemCommand(
                f"Next {label}", f"Run to the next {label} and pause (t, j)", self._seek_to(k)
            )
        yield SystemCommand(
            "Back 10 s", "Show the sample 10 s of log earlier (b)", self.action_seek_back
        )
        yield SystemCommand(
            "Restart replay", "Play the log from the start (0)", self.action_restart
        )

    def _seek_to(self, k: int) -> Callable[[], None]:
        def go() -> None:
            self.target = k
            self.action_next_failure()

        return go


def create_app(session: Any, **kwargs: Any) -> BenchApp:
    """The App for ``session``: :class:`ReplayApp` for a replay, else :class:`BenchApp`."""
    if getattr(session, "replay", None) is not None:
        return ReplayApp(session, **kwargs)
    kwargs.pop("restart", None)
    kwargs.pop("recorded_marks", None)
    return BenchApp(session, **kwargs)
