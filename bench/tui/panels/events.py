"""Events: a scrolling log of vote failures, faults and link errors; operator marks apart.

The runner keeps the newest 500 events; each poll adds only those not yet shown. A fault
that repeats every sample (a flagged channel at 1 kHz) would bury everything else, so an
event like one of the last few rows (same text but for the sample number) is counted into
that row instead: "STATUS_FLAG ch2 status SELFTEST ×200 #300-499" (samples 300 to 499), and
the row's time is that of its latest occurrence. Operator marks go to a list of their own
(:class:`MarksPanel`) so that a stream of vote failures cannot scroll them away. The list can
be narrowed to one kind of event (:meth:`EventsPanel.cycle_filter`, key ``f``).
Times are receive times in UTC, or the log's own times in a replay, as in the MCAP file: UTC
where a wall clock stamped them, else the log's run time (an emulator's log starts at 0).
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Any

from rich.text import Text
from textual.widgets import DataTable
from textual.widgets.data_table import RowKey

from bench.records.events import EventKind, severity

STYLE = {"info": "cyan", "warning": "yellow", "error": "bold red"}
MAX_ROWS = 500
EVENT_WIDTH = 160
"""Text column width: wider than any panel (cropped there), never re-measured per update."""
MERGE_DEPTH = 4
"""How many of the newest rows a repeating event may be counted into."""
_SAMPLE = re.compile(r" sample (\d+)")
TIME_WIDTH = 13
MARK_WIDTH = 32
"""The marks panel's one column (time and text, wrapped): its content width."""


def stamp(t: float) -> str:
    if t != t:  # NaN
        return "--:--:--.---"
    return time.strftime("%H:%M:%S", time.gmtime(t)) + f".{int((t % 1) * 1000):03d}"


def kind_name(kind: int) -> str:
    return EventKind(kind).name if kind in EventKind._value2member_map_ else f"kind {kind}"


@dataclass
class Row:
    key: str  # the text without its sample number
    kind: int
    text: str
    t: float = float("nan")  # the latest occurrence
    count: int = 1
    first_n: int = -1
    last_n: int = -1
    row_key: RowKey | None = None  # the table row showing it (None: filtered out or not yet added)

    def label(self) -> Text:
        style = "bold magenta" if self.kind == EventKind.MARK else STYLE.get(severity(self.kind))
        out = Text(self.text if self.count == 1 else self.key, style=style or "")
        if self.count > 1:
            out.append(f" ×{self.count}", style="bold")
            if self.first_n >= 0:
                out.append(f" #{self.first_n}-{self.last_n}", style="dim")
        return out

    def when(self) -> Text:
        return Text(stamp(self.t), style="dim")


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


def merge_events(
    rows: list[Row], fresh: list[tuple[float, int, str]]
) -> tuple[list[Row], list[Row]]:
    """Count ``fresh`` events into the newest rows of ``rows`` where they repeat one (same text
    but for the sample number), else make new rows. Returns (new rows, existing rows changed);
    a merged row takes the time and sample number of its latest occurrence."""
    added: list[Row] = []
    changed: dict[int, Row] = {}
    for t, kind, text in fresh:
        key, n = split_sample(text)
        recent = [*rows[-MERGE_DEPTH:], *added[-MERGE_DEPTH:]][-MERGE_DEPTH:]
        hit = next((r for r in reversed(recent) if r.key == key), None)
        if hit is not None and n >= 0:
            hit.count += 1
            hit.last_n = n
            hit.t = t
            if not any(hit is r for r in added):
                changed[id(hit)] = hit
        else:
            added.append(Row(key, kind, text, t=t, first_n=n, last_n=n))
    return added, list(changed.values())


class _EventTable(DataTable):
    """A two-column (time, text) log, newest at the bottom; follows the newest row unless
    the operator has clicked in and scrolled up."""

    TITLE = "Events"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(show_header=False, cursor_type="none", cell_padding=0, **kwargs)
        self._rows: list[Row] = []
        self.clock = "UTC"

    def on_mount(self) -> None:
        self._columns()
        self._title()

    def _columns(self) -> None:
        self.add_column("time", key="time", width=TIME_WIDTH)
        self.add_column("event", key="event", width=EVENT_WIDTH)

    def set_clock(self, clock: str) -> None:
        """What the time column is: "UTC" (receive time), "log time, UTC" (a replay of a
        log stamped by a wall clock) or "run time" (a log with its own time base)."""
        if clock != self.clock:
            self.clock = clock
            self._title()

    def _title(self) -> None:
        self.border_title = f"{self.TITLE} ({self.clock})"

    def _shown(self, row: Row) -> bool:
        return True

    def _add(self, row: Row) -> RowKey:
        return self.add_row(row.when(), row.label())

    def _put(self, added: list[Row], changed: list[Row]) -> None:
        """One table operation per row, however many events arrived: a fault that repeats
        every sample at 1 kHz must not cost the UI thread thousands of cell updates."""
        follow = not self.has_focus or self.scroll_y >= self.max_scroll_y - 1
        for row in changed:
            if row.row_key is not None:
                self.update_cell(row.row_key, "time", row.when())
                self.update_cell(row.row_key, "event", row.label())
        for row in added[-MAX_ROWS:]:
            if self._shown(row):
                row.row_key = self._add(row)
            self._rows.append(row)
        excess = len(self._rows) - MAX_ROWS
        if excess > 0:
            for old in self._rows[:excess]:
                if old.row_key is not None:
                    self.remove_row(old.row_key)
            del self._rows[:excess]
        if follow:
            self.scroll_end(animate=False, immediate=False)

    def _rebuild(self) -> None:
        self.clear()
        for row in self._rows:
            row.row_key = self._add(row) if self._shown(row) else None
        self.scroll_end(animate=False, immediate=False)

    def reset(self) -> None:
        """Forget every row (a replay started again from the beginning)."""
        self._rows = []
        self.clear()

    def texts(self) -> list[str]:
        """The rows shown, as 'time text' (tests)."""
        return [f"{r.when().plain} {r.label().plain}" for r in self._rows if r.row_key is not None]


class MarksPanel(_EventTable):
    """Operator marks (and tolerance changes), newest at the bottom, never merged; a narrow
    panel, so a long mark wraps onto a second line instead of being cut."""

    TITLE = "Marks"

    def _columns(self) -> None:
        self.add_column("mark", key="event", width=MARK_WIDTH)

    def _add(self, row: Row) -> RowKey:
        text = Text(stamp(row.t)[:8] + " ", style="dim")
        text.append(row.text.removeprefix("MARK "), style="bold magenta")
        return self.add_row(text, height=None)

    def texts(self) -> list[str]:
        return [
            f"{stamp(r.t)[:8]} {r.text.removeprefix('MARK ')}"
            for r in self._rows
            if r.row_key is not None
        ]

    def add(self, events: list[tuple[float, int, str]]) -> None:
        if events:
            self._put([Row(text, kind, text, t=t) for t, kind, text in events], [])
            self.border_subtitle = f"{len(self._rows)}"


class EventsPanel(_EventTable):
    """Every event but operator marks (those go to the :class:`MarksPanel` given), merged
    where they repeat, optionally narrowed to one kind."""

    def __init__(self, marks: MarksPanel | None = None, **kwargs: object) -> None:
        super().__init__(**kwargs)
        self._last: tuple[float, int, str] | None = None
        self.marks = marks
        self.received = 0
        self.only: int | None = None  # the one kind shown, or None: all
        self.kinds_seen: set[int] = set()

    def _shown(self, row: Row) -> bool:
        return self.only is None or row.kind == self.only

    def show(self, events: list[tuple[float, int, str]]) -> None:
        fresh, missed = new_events(events, self._last)
        if not fresh:
            return
        marks = [e for e in fresh if e[1] == EventKind.MARK]
        others = [e for e in fresh if e[1] != EventKind.MARK]
        if self.marks is not None:
            self.marks.add(marks)
        else:
            others = fresh
        added, changed = merge_events(self._rows, others)
        self.kinds_seen.update(r.kind for r in added)
        if missed:
            added.insert(0, Row("…", int(EventKind.MARK), "… more events than the buffer"))
        self._put(added, changed)
        self._last = fresh[-1]
        self.received += len(fresh)
        self._subtitle()

    def reset(self) -> None:
        super().reset()
        self._last = None
        self.received = 0
        self.kinds_seen = set()
        if self.marks is not None:
            self.marks.reset()
        self._subtitle()

    def _subtitle(self) -> None:
        shown = "all" if self.only is None else kind_name(self.only)
        self.border_subtitle = f"f: {shown} · events: {self.received}"

    def set_filter(self, kind: int | None) -> None:
        """Show only events of ``kind`` (None: all)."""
        self.only = kind
        self._rebuild()
        self._subtitle()

    def cycle_filter(self) -> int | None:
        """All -> each kind seen so far, in EventKind order -> all."""
        kinds = sorted(self.kinds_seen - {int(EventKind.MARK)} if self.marks else self.kinds_seen)
        if not kinds:
            nxt = None
        elif self.only is None or self.only not in kinds:
            nxt = kinds[0] if self.only is None else None
        else:
            i = kinds.index(self.only)
            nxt = kinds[i + 1] if i + 1 < len(kinds) else None
        self.set_filter(nxt)
        return nxt
