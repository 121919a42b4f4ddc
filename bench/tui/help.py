"""The help screen (``?``): every key of the current mode, and what the panels show.

Built from the App's own bindings, so it cannot drift from what the keys do. Escape, ``?``
or ``q`` close it.
"""

from __future__ import annotations

from typing import ClassVar

from rich.table import Table
from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding, BindingType
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Static

PANELS = (
    ("Per pair", "g12 g23 g13, weights, votes PASS/FAIL with |Δ|, final gradient and ours"),
    ("Per channel", "code, acceleration, status bits, rate from receive times, gaps, CRC"),
    ("Gradient", "final (white, on top), g12 g23 g13 and ours over the window (w)"),
    ("Source & board", "BOARD_STATUS, speed, frames recv/sent/drop, queue, latency, bus"),
    ("Events", "faults, vote failures, exclusions; repeats counted into one row (f filters)"),
    ("Marks", "operator marks and tolerance changes, never scrolled away by events"),
    ("Recording", "the MCAP file being written, its size, frames, drops"),
)


def help_table(keys: list[tuple[str, str]], replay: bool) -> Table:
    table = Table(box=None, show_header=False, padding=(0, 2, 0, 0))
    table.add_column(style="bold cyan", no_wrap=True)
    table.add_column()
    table.add_row(Text("Keys", style="bold underline"), "")
    for key, what in keys:
        table.add_row(key, what)
    table.add_row("ctrl+p", "command palette (every action, by name)")
    table.add_row("escape", "close this help, the palette, or leave the Events list")
    table.add_row("", "")
    table.add_row(Text("Panels", style="bold underline"), "")
    for name, what in PANELS:
        table.add_row(name, what)
    if replay:
        table.add_row("", "")
        table.add_row("", Text("Replay: times are the log's own (UTC).", style="dim"))
    return table


class HelpScreen(ModalScreen[None]):
    """A modal over the running screen: acquisition and logging go on underneath."""

    DEFAULT_CSS = """
    HelpScreen { align: center middle; }
    HelpScreen > VerticalScroll {
        width: 90; max-width: 100%; height: auto; max-height: 100%;
        border: round $accent; background: $surface; padding: 0 1;
    }
    """
    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("escape,question_mark,q", "close", "Close", show=False),
    ]

    def __init__(self, keys: list[tuple[str, str]], *, replay: bool = False) -> None:
        super().__init__()
        self._keys = keys
        self._replay = replay

    def compose(self) -> ComposeResult:
        with VerticalScroll() as box:
            box.border_title = "Help · escape closes"
            yield Static(help_table(self._keys, self._replay), id="help-text")

    def action_close(self) -> None:
        self.dismiss(None)
