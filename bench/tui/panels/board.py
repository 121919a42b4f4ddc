"""Source and board panel: where frames come from, the board's own status, the speed
reference, and every counter that says whether the receive path is keeping up."""

from __future__ import annotations

from rich.text import Text
from textual.widgets import Static

from bench.live.view import Snapshot
from bench.records.events import EventKind
from bench.tui.panels import MISSING, num
from protocol.layout import BoardState

STATE_STYLE = {
    BoardState.BOOT: "yellow",
    BoardState.RUN: "green",
    BoardState.DEGRADED: "bold yellow",
    BoardState.FAULT: "bold red",
}


def board_lines(s: Snapshot, *, live: bool = True) -> Text:
    """One line per topic, label first; the panel cuts long lines with an ellipsis."""
    out = Text(no_wrap=True, overflow="ellipsis")

    def line(label: str, value: Text | str) -> None:
        if out:
            out.append("\n")
        out.append(f"{label:<8}", style="bold")
        out.append(value)

    line("source", s.source)
    b = s.board
    if b is None:
        line("board", Text("no BOARD_STATUS yet", style="dim"))
    else:
        state = int(b["state"])
        known = state in BoardState._value2member_map_
        text = Text(BoardState(state).name if known else f"state {state}")
        text.stylize(STATE_STYLE[BoardState(state)] if known else "bold red")
        text.append(
            f" {int(b['sample_rate'])} Hz {int(b['temperature'])} °C "
            f"{int(b['supply']) * 0.1:.1f} V err {int(b['errors'])}"
        )
        line("board", text)
    sp = s.speed
    if sp is None:
        line("speed", Text("no SPEED_REF", style="dim"))
    else:
        v = int(sp["speed"]) / 1000.0
        line("speed", f"{v:+.3f} m/s  {v * 3.6:+.1f} km/h")
    sent = s.extra.get("frames_sent")
    frames = Text(f"{s.frames_received} recv")
    if sent is not None:
        frames.append(f" / {sent} sent")
    frames.append("  drop ")
    frames.append(str(s.frames_dropped), style="bold red" if s.frames_dropped else "")
    line("frames", frames)
    queue = f"{s.queue_depth}/{s.queue_max}"
    if live:
        p50, p99 = s.latency_ms
        queue += f"  latency {num(p50, '.1f')}/{num(p99, '.1f')} ms"
    line("queue", queue)
    st = s.stats
    err = Text()
    for label, n in (
        ("CRC", st.crc_errors),
        ("DLC", st.wrong_dlc),
        ("ID", st.unknown_id),
        ("link", st.link_errors),
        ("parse", st.parse_errors),
        ("disc", st.events.get(int(EventKind.DISCONNECT), 0)),
        ("kdrop", st.socket_drops),  # frames the kernel dropped at the socket (socketcan)
    ):
        err.append(f"{label} ")
        style = "yellow" if n and label != "ID" else ""
        err.append(str(n), style="bold red" if n and label == "kdrop" else style)
        err.append(" ")
    line("bus", err)
    valid = f"{100.0 * st.valid / st.samples:.1f} %" if st.samples else MISSING
    line("samples", f"{st.samples} lost {st.samples_lost} valid {valid}")
    return out


class BoardPanel(Static):
    def on_mount(self) -> None:
        self.border_title = "Source & board"

    def show(self, s: Snapshot, *, live: bool = True) -> None:
        self.update(board_lines(s, live=live), layout=False)
        self.border_subtitle = Text(s.error, style="bold red") if s.error else ""
