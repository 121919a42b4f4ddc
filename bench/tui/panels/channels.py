"""Per-channel panel: raw code, calibrated acceleration, status bits by name, frame rate,
gaps, duplicates/late frames and CRC errors for ch1..ch3."""

from __future__ import annotations

from collections import deque

import numpy as np
from rich.table import Table
from rich.text import Text
from textual.widgets import Static

from bench.pipeline.stats import Stats
from bench.tui.panels import MISSING, num
from protocol.layout import STATUS_FAULT_MASK, status_names

RATE_WINDOW_S = 2.0
"""Receive-time span the current frame rate is averaged over."""


class RateMeter:
    """Current frame rate per channel from the frame counts and *receive times* of successive
    snapshots, so the figure does not depend on how often the UI polls.

    Until two snapshots span some receive time, the whole-run average is used. A channel that
    stops arriving reads 0 after ``stale_s`` of wall time without a new frame.
    """

    def __init__(self, stale_s: float = 1.5) -> None:
        self.stale_s = stale_s
        self._hist: list[deque[tuple[int, float, float]]] = [deque(maxlen=64) for _ in range(3)]

    def update(self, stats: Stats, wall: float) -> list[float]:
        out = []
        for ch, cs in enumerate(stats.channels):
            hist = self._hist[ch]
            if not hist or hist[-1][0] != cs.frames:
                hist.append((cs.frames, cs.last_t, wall))
            frames, last_t, seen = hist[-1]
            if wall - seen > self.stale_s and len(hist) > 1:
                out.append(0.0)
                continue
            old = None
            for entry in hist:
                if last_t - entry[1] <= RATE_WINDOW_S:
                    old = entry
                    break
            if old is not None and old[0] < frames and last_t > old[1]:
                out.append((frames - old[0]) / (last_t - old[1]))
            else:
                out.append(cs.rate_hz())
        return out


def channel_table(row: np.void | None, stats: Stats, rates: list[float]) -> Table:
    table = Table(box=None, pad_edge=False, padding=0, show_edge=False)
    table.add_column("", style="bold", min_width=9, no_wrap=True)
    for ch in (1, 2, 3):
        table.add_column(f"ch{ch}", justify="right", min_width=10, no_wrap=True)

    def row3(label: str, cells: list[Text | str]) -> None:
        table.add_row(label, *cells)

    if row is None:
        row3("code", [MISSING] * 3)
        row3("acc m/s²", [MISSING] * 3)
        row3("status", [MISSING] * 3)
    else:
        present = row["present"]
        row3(
            "code",
            [f"{int(row['code'][k]):+d}" if present[k] else MISSING for k in range(3)],
        )
        row3("acc m/s²", [num(row["acc"][k], "+.5f") for k in range(3)])
        cells: list[Text | str] = []
        for k in range(3):
            if not present[k]:
                cells.append(Text("missing", style="bold red"))
                continue
            st = int(row["status"][k])
            names = status_names(st)
            if st & STATUS_FAULT_MASK:
                cells.append(Text("|".join(names), style="bold red"))
            elif st:
                cells.append(Text(f"0x{st:02X}", style="yellow"))
            else:
                cells.append(Text("ok", style="green"))
        row3("status", cells)
    chans = stats.channels
    row3("rate Hz", [num(r, ".1f") for r in rates])
    row3("frames", [f"{c.frames}" for c in chans])
    row3("gaps", [_count(c.gaps) for c in chans])
    row3("dup/late", [_count(c.duplicates + c.late, f"{c.duplicates}/{c.late}") for c in chans])
    row3("CRC err", [_count(c.crc_errors) for c in chans])
    return table


def _count(n: int, text: str | None = None) -> Text:
    return Text(text if text is not None else str(n), style="yellow" if n else "")


class ChannelsPanel(Static):
    """The three channels side by side."""

    def on_mount(self) -> None:
        self.border_title = "Per channel"

    def show(self, row: np.void | None, stats: Stats, rates: list[float]) -> None:
        self.update(channel_table(row, stats, rates), layout=False)
        flagged = sum(c.status_flagged for c in stats.channels)
        self.border_subtitle = f"status-flagged {flagged}" if flagged else ""
