"""Recording panel: the current MCAP file, its size, frames and duration, and whether the
log is keeping up (its own drop counter); r starts and stops a recording."""

from __future__ import annotations

from rich.table import Table
from rich.text import Text
from textual.widgets import Static

from bench.sinks.base import RecordingStatus
from bench.tui.panels import MISSING, duration_text, size_text


def recording_table(
    status: RecordingStatus | None, last: RecordingStatus | None, stream: str | None = None
) -> Table:
    """The panel's rows; ``stream``: the live Foxglove stream's address (``--foxglove``; a
    port chosen at start is shown nowhere else once the screen is up), on the first row."""
    table = Table(box=None, pad_edge=False, padding=0, show_header=False, show_edge=False)
    table.add_column(overflow="fold", ratio=1)
    if stream:
        table.add_row(Text(f"Foxglove {stream}", style="cyan"))
    if status is None:
        table.add_row(Text("○ not recording: press r to start", style="dim"))
        if last:
            table.add_row(Text("last file:", style="bold"))
            table.add_row(str(last.path or MISSING))
            table.add_row(_figures(last))
        return table
    head = Text("● REC ", style="bold red")
    head.append(duration_text(status.duration_s), style="bold")
    if status.queue is not None:
        head.append(f"  queue {status.queue}", style="dim")
    table.add_row(head)
    path = str(status.path or MISSING)
    if status.error:  # before the long path, where a short panel cannot crop it away
        reason = status.error.removeprefix(f"{path}: ")
        table.add_row(Text(f"LOG FAILED: {reason}", style="bold red"))
    table.add_row(path)
    line = Text(_figures(status, duration=False))
    for key, value in (("dropped", status.dropped), ("lost", status.lost)):
        if value:
            line.append(f"  {key} {value}", style="bold red")
    table.add_row(line)
    return table


def _figures(status: RecordingStatus, *, duration: bool = True) -> str:
    parts = [size_text(status.bytes)]
    if status.error:  # the writer's count is not what the file holds
        if status.file_frames is not None:
            parts.append(f"{status.file_frames} frames in the file")
    elif status.frames is not None:
        parts.append(f"{status.frames} frames")
    if duration:
        parts.append(duration_text(status.duration_s))
    return "  ".join(parts)


class RecordingPanel(Static):
    def on_mount(self) -> None:
        self.border_title = "Recording"

    def show(
        self,
        status: RecordingStatus | None,
        last: RecordingStatus | None = None,
        stream: str | None = None,
    ) -> None:
        self.update(recording_table(status, last, stream), layout=False)
        self.set_class(status is not None, "recording")
