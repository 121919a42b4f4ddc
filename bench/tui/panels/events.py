"""Events: a scrolling log of vote failures, faults, link errors and operator marks.

The runner keeps the newest 500 events; each poll adds only those not yet shown. A fault
that repeats every sample (a flagged channel at 1 kHz) would bury everything else, so an
event like one of the last few rows (same text but for the sample number) is counted into
that row instead: "STATUS_FLAG ch2 status SELFTEST ×200 #300-499" (samples 300 to 499).
Times are receive times in UTC (log times in a replay), as in the MCAP file.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass

from rich.text import Text
from textual.widgets import DataTable

from bench.records.events import EventKind, severity

STYLE = {"info": "cyan", "warning": "yellow", "error": "bold red"}
MAX_ROWS = 500
EVENT_WIDTH = 96
"""Fixed text column width (cropped by the panel): no re-measuring on every update."""
MERGE_DEPTH = 4
"""How many of the newest rows a repeating event may be counted into."""
_SAMPLE = re.compile(r" sample (\d+)")


def stamp(t: float) -> str:
    if t != t:  # NaN
        return "--:--:--.---"
    return time.strftime("%H:%M:%S", time.gmtime(t)) + f".{int((t % 1) * 1000):03d}"


@dataclass
class Row:
    key: str  # the text without its sample number
    kind: int
    text: str
    count: int = 1
    first_n: int = -1
    last_n: int = -1
    row_key: object = None

    def label(self) -> Text:
        style = "bold magenta" if self.kind == EventKind.MARK else STYLE.get(severity(self.kind))
        out = Text(self.text if self.count == 1 else self.key, style=style or "")
        if self.count > 1:
            out.append(f" ×{self.count}", style="bold")
            if self.first_n >= 0:
                out.append(f" #{self.first_n}-{self.last_n}", style="dim")
        return out


def split_sample(text: str) -> tuple[str, int]:
    """'GAP ch3 sample 12 x' -> ('GAP ch3 x', 12); -1 when the text names no sample."""
    m = _SAMPLE.search(text)
    if not m:
        return text, -1
    return text[: m.start()] + text[m.end() :], int(m.group(1))


def new_events(
    events: list[tuple[float, int, str]], last: tuple[float, int, str] | None
) -> tuple[list[tuple[float, int, str]], bool]:
    """The events after ``last`` (the newest one already shown), and whether some were missed
    because more than the runner's buffer arrived between two polls."""
    if last is None:
        return events, False
    for i in range(len(events) - 1, -1, -1):
        if events[i] == last:
            return events[i + 1 :], False
    return events, True


class EventsPanel(DataTable):
    """Newest at the bottom; follows it unless the operator has clicked in and scrolled up."""

    def __init__(self, **kwargs: object) -> None:
        super().__init__(show_header=False, cursor_type="none", cell_padding=0, **kwargs)  # type: ignore[arg-type]
        self._last: tuple[float, int, str] | None = None
        self._rows: list[Row] = []
        self.received = 0

    def on_mount(self) -> None:
        self.border_title = "Events (UTC)"
        self.add_column("time", key="time", width=13)
        self.add_column("event", key="event", width=EVENT_WIDTH)

    def show(self, events: list[tuple[float, int, str]]) -> None:
        fresh, missed = new_events(events, self._last)
        if not fresh:
            return
        # follow the newest row unless the operator is reading back (focused and scrolled up)
        follow = not self.has_focus or self.scroll_y >= self.max_scroll_y - 1
        pending: list[tuple[Row, float]] = []  # rows to add, with the time of their first event
        dirty: dict[int, Row] = {}  # rows already on screen whose count changed
        if missed:
            pending.append((Row("…", int(EventKind.MARK), "… more events than the buffer"), 0.0))
        for t, kind, text in fresh:
            key, n = split_sample(text)
            recent = [*self._rows[-MERGE_DEPTH:], *(r for r, _ in pending[-MERGE_DEPTH:])]
            hit = next((r for r in reversed(recent[-MERGE_DEPTH:]) if r.key == key), None)
            if hit is not None and n >= 0:
                hit.count += 1
                hit.last_n = n
                if hit.row_key is not None:
                    dirty[id(hit)] = hit
            else:
                pending.append((Row(key, kind, text, first_n=n, last_n=n), t))
        # one table operation per row, however many events arrived: a fault that repeats
        # every sample at 1 kHz must not cost the UI thread thousands of cell updates
        for row in dirty.values():
            self.update_cell(row.row_key, "event", row.label())  # type: ignore[arg-type]
        for row, t in pending[-MAX_ROWS:]:
            row.row_key = self.add_row(Text(stamp(t), style="dim"), row.label())
            self._rows.append(row)
        excess = len(self._rows) - MAX_ROWS
        if excess > 0:
            for old in self._rows[:excess]:
                self.remove_row(old.row_key)  # type: ignore[arg-type]
            del self._rows[:excess]
        self._last = fresh[-1]
        self.received += len(fresh)
        self.border_subtitle = f"events: {self.received}"
        if follow:
            self.scroll_end(animate=False, immediate=False)
