"""Recording panel: the current MCAP file, its size, frames and duration, and whether the
log is keeping up (its own drop counter); r starts and stops a recording."""

from __future__ import annotations

from rich.table import Table
from rich.text import Text
from textual.widgets import Static

from bench.pipeline.warmup import WarmUpStatus
from bench.sinks.base import RecordingStatus
from bench.tui.panels import MISSING, duration_text, size_text


def recording_table(
    status: RecordingStatus | None,
    last: RecordingStatus | None,
    stream: str | None = None,
    width: int | None = None,
    held: WarmUpStatus | None = None,
) -> Table:
    """Two lines while recording (three when the log failed, or while ``held`` frames wait
    for the estimator's kernel): state, duration and figures; the file, cut at its start to
    ``width`` (the name is what tells files apart), so the Marks list below keeps its rows
    at 100x30. ``stream``: the live Foxglove stream's address (``--foxglove``; a port chosen
    at start is shown nowhere else once the screen is up), on the first row."""
    table = Table(box=None, pad_edge=False, padding=0, show_header=False, show_edge=False)
    table.add_column(no_wrap=True, overflow="ellipsis", ratio=1)
    if stream:
        table.add_row(Text(f"Foxglove {stream}", style="cyan"))
    if status is None:
        if not last:
            table.add_row(Text("○ not recording: press r to start", style="dim"))
            return table
        table.add_row(Text("○ not recording (r starts)  last:", style="dim"))
        table.add_row(_figures(last))
        table.add_row(_path(last.path, width))
        return table
    head = Text()
    head.append("● REC ", style="bold red")
    head.append(duration_text(status.duration_s), style="bold red")
    head.append("  " + _figures(status, duration=False))
    for key, value in (("dropped", status.dropped), ("lost", status.lost)):
        if value:
            head.append(f"  {key} {value}", style="bold red")
    if status.queue is not None:
        head.append(f"  queue {status.queue}", style="dim")
    table.add_row(head)
    path = str(status.path or MISSING)
    if status.error:  # before the path, where a short panel cannot crop it away
        reason = status.error.removeprefix(f"{path}: ")
        table.add_row(Text(f"LOG FAILED: {reason}", style="bold red"))
    if held is not None:
        line = Text(f"{held.held_frames} frames held for the estimator", style="yellow")
        if held.dropped_frames:  # the hold is bounded: beyond it the log loses frames
            line.append(f"  drop {held.dropped_frames}", style="bold red")
        table.add_row(line)
    table.add_row(_path(status.path, width))
    return table


def _path(path: str | None, width: int | None) -> str:
    """The path, its start replaced by … when it is wider than ``width``."""
    text = str(path or MISSING)
    if width is None or width < 2 or len(text) <= width:
        return text
    return "…" + text[len(text) - width + 1 :]


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
    _rows = 0  # lines shown: the panel's height (auto) is laid out again only when they change

    def on_mount(self) -> None:
        self.border_title = "Recording"

    def show(
        self,
        status: RecordingStatus | None,
        last: RecordingStatus | None = None,
        stream: str | None = None,
        held: WarmUpStatus | None = None,
    ) -> None:
        """``held``: the estimator's preparation (frames waiting for its kernel, logged once
        it is ready; those beyond the hold's bound dropped)."""
        table = recording_table(status, last, stream, self.content_size.width or None, held)
        self.update(table, layout=table.row_count != self._rows)
        self._rows = table.row_count
        self.set_class(status is not None, "recording")
