"""Source and board panel: where frames come from, the board's own status, the speed
reference, and every counter that says whether the receive path is keeping up."""

from __future__ import annotations

from rich.text import Text
from textual.widgets import Static

from bench.live.view import Snapshot
from bench.records.events import EventKind
from bench.tui.panels import MISSING, labelled, num
from protocol.layout import BoardState

STATE_STYLE = {
    BoardState.BOOT: "yellow",
    BoardState.RUN: "green",
    BoardState.DEGRADED: "bold yellow",
    BoardState.FAULT: "bold red",
}


def board_lines(s: Snapshot, *, live: bool = True, rows: int | None = None) -> Text:
    """One line per topic, label first; the panel cuts long lines with an ellipsis. With
    fewer than ``rows`` lines of room (100x30) the source line goes first: the status bar
    names the source too."""
    lines: list[tuple[str, Text | str]] = [("source", s.source)]
    b = s.board
    if b is None:
        lines.append(("board", Text("no BOARD_STATUS yet", style="dim")))
    else:
        state = int(b["state"])
        known = state in BoardState._value2member_map_
        text = Text(BoardState(state).name if known else f"state {state}")
        text.stylize(STATE_STYLE[BoardState(state)] if known else "bold red")
        text.append(
            f" {int(b['sample_rate'])} Hz {int(b['temperature'])} °C "
            f"{int(b['supply']) * 0.1:.1f} V err {int(b['errors'])}"
        )
        lines.append(("board", text))
    sp = s.speed
    if sp is None:
        lines.append(("speed", Text("no SPEED_REF", style="dim")))
    else:
        v = int(sp["speed"]) / 1000.0
        lines.append(("speed", f"{v:+.3f} m/s  {v * 3.6:+.1f} km/h"))
    sent = s.extra.get("frames_sent")
    frames = Text(f"{s.frames_received} recv")
    if sent is not None:
        frames.append(f" / {sent} sent")
    frames.append("  drop ")
    frames.append(str(s.frames_dropped), style="bold red" if s.frames_dropped else "")
    lines.append(("frames", frames))
    queue = f"{s.queue_depth}/{s.queue_max}"
    if live:
        p50, p99 = s.latency_ms
        queue += f"  latency {num(p50, '.1f')}/{num(p99, '.1f')} ms"
    lines.append(("queue", queue))
    st = s.stats
    # what the bus or the source lost (frames never seen), then what arrived broken: two
    # lines, so that at 100 columns neither is cut
    lines.append(
        (
            "bus",
            _counts(
                ("kdrop", st.socket_drops, "bold red"),  # frames the kernel dropped (socketcan)
                ("disc", st.events.get(int(EventKind.DISCONNECT), 0), "yellow"),
                ("parse", st.parse_errors, "yellow"),
            ),
        )
    )
    lines.append(
        (
            "errors",
            _counts(
                ("CRC", st.crc_errors, "yellow"),
                ("DLC", st.wrong_dlc, "yellow"),
                ("UART", st.link_errors, "yellow"),
                ("ID", st.unknown_id, ""),
            ),
        )
    )
    valid = f"{100.0 * st.valid / st.samples:.1f} %" if st.samples else MISSING
    lines.append(("samples", f"{st.samples} lost {st.samples_lost} valid {valid}"))
    if rows is not None and len(lines) > rows:
        lines = lines[1:]
    return labelled(lines)


def _counts(*counts: tuple[str, int, str]) -> Text:
    """``label n`` pairs, each count in its style when it is not zero."""
    text = Text()
    for label, n, style in counts:
        if text:
            text.append("  ")
        text.append(f"{label} ")
        text.append(str(n), style=style if n else "")
    return text


class BoardPanel(Static):
    def on_mount(self) -> None:
        self.border_title = "Source & board"

    def show(self, s: Snapshot, *, live: bool = True) -> None:
        rows = self.content_size.height or None
        self.update(board_lines(s, live=live, rows=rows), layout=False)
        self.border_subtitle = Text(s.error, style="bold red") if s.error else ""
