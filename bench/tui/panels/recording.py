"""Recording panel: the current MCAP file, its size, frames and duration, and whether the
log is keeping up (its own drop counter); r starts and stops a recording."""

from __future__ import annotations

from typing import Any

from rich.table import Table
from rich.text import Text
from textual.widgets import Static

from bench.tui.panels import MISSING, duration_text, size_text

_SIZE_KEYS = ("bytes", "size_bytes", "size")
_DURATION_KEYS = ("duration_s", "duration")
_SHOWN = {
    "path",
    "lost",
    "queue",
    "frames",
    "results",
    "dropped",
    "error",
    "errors",
    "marks",
    "closed",
    *_SIZE_KEYS,
    *_DURATION_KEYS,
}


def _first(status: dict[str, Any], keys: tuple[str, ...]) -> Any:
    for k in keys:
        if k in status and status[k] is not None:
            return status[k]
    return None


def recording_table(status: dict[str, Any] | None, last: dict[str, Any] | None) -> Table:
    table = Table(box=None, pad_edge=False, padding=0, show_header=False, show_edge=False)
    table.add_column(overflow="fold", ratio=1)
    if status is None:
        table.add_row(Text("○ not recording: press r to start", style="dim"))
        if last:
            table.add_row(Text("last file:", style="bold"))
            table.add_row(str(last.get("path", MISSING)))
            table.add_row(_figures(last))
        return table
    head = Text("● REC ", style="bold red")
    head.append(duration_text(_first(status, _DURATION_KEYS)), style="bold")
    if "queue" in status:
        head.append(f"  queue {status['queue']}", style="dim")
    table.add_row(head)
    path = str(status.get("path", MISSING))
    err = status.get("error") or status.get("errors")
    if err:  # before the long path, where a short panel cannot crop it away
        reason = str(err).removeprefix(f"{path}: ")
        table.add_row(Text(f"LOG FAILED: {reason}", style="bold red"))
    table.add_row(path)
    line = Text(_figures(status, duration=False))
    for key in ("dropped", "lost"):
        if status.get(key):
            line.append(f"  {key} {status[key]}", style="bold red")
    table.add_row(line)
    extra = [f"{k} {v}" for k, v in status.items() if k not in _SHOWN and _is_scalar(v)]
    if extra:
        table.add_row(Text("  ".join(extra), style="dim"))
    return table


def _figures(status: dict[str, Any], *, duration: bool = True) -> str:
    parts = [size_text(_first(status, _SIZE_KEYS))]
    if "frames" in status:
        parts.append(f"{status['frames']} frames")
    if duration:
        parts.append(duration_text(_first(status, _DURATION_KEYS)))
    return "  ".join(parts)


def _is_scalar(v: Any) -> bool:
    return isinstance(v, int | float | str | bool)


class RecordingPanel(Static):
    def on_mount(self) -> None:
        self.border_title = "Recording"

    def show(self, status: dict[str, Any] | None, last: dict[str, Any] | None = None) -> None:
        self.update(recording_table(status, last), layout=False)
        self.set_class(status is not None, "recording")
