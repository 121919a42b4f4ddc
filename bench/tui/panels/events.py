"""Events: a scrolling log of vote failures, faults, link errors and operator marks.

The runner keeps the newest 500 events; each poll appends only those not yet shown.
Times are receive times in UTC (log times in a replay), so the screen and the MCAP agree.
"""

from __future__ import annotations

import time

from rich.text import Text
from textual.widgets import RichLog

from bench.events import EventKind, severity

STYLE = {"info": "cyan", "warning": "yellow", "error": "bold red"}
MAX_LINES = 1000


def event_line(t: float, kind: int, text: str) -> Text:
    if t == t:  # not NaN
        stamp = time.strftime("%H:%M:%S", time.gmtime(t)) + f".{int((t % 1) * 1000):03d}"
    else:
        stamp = "--:--:--.---"
    line = Text(stamp + " ", style="dim")
    style = "bold magenta" if kind == EventKind.MARK else STYLE.get(severity(kind), "")
    line.append(text, style=style)
    return line


def new_events(
    events: list[tuple[float, int, str]], last: tuple[float, int, str] | None
) -> tuple[list[tuple[float, int, str]], int]:
    """The events after ``last`` (the newest one already shown) and how many were missed
    because more than the runner's buffer arrived between two polls."""
    if last is None:
        return events, 0
    for i in range(len(events) - 1, -1, -1):
        if events[i] == last:
            return events[i + 1 :], 0
    return events, 1


class EventsPanel(RichLog):
    def __init__(self, **kwargs: object) -> None:
        super().__init__(max_lines=MAX_LINES, wrap=False, markup=False, **kwargs)  # type: ignore[arg-type]
        self._last: tuple[float, int, str] | None = None
        self.shown = 0

    def on_mount(self) -> None:
        self.border_title = "Events (UTC)"

    def show(self, events: list[tuple[float, int, str]]) -> None:
        fresh, missed = new_events(events, self._last)
        if missed:
            self.write(Text("… more events than the buffer holds; older ones skipped", "dim"))
        for t, kind, text in fresh[-MAX_LINES:]:
            self.write(event_line(t, kind, text))
        if fresh:
            self._last = fresh[-1]
            self.shown += len(fresh)
        self.border_subtitle = f"{self.shown} shown"
