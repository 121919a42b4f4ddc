"""The closing summary of a run or replay, as a rich table."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.pipeline.stats import Stats

if TYPE_CHECKING:  # rich is imported when a table is made: a quiet command never needs it
    from rich.console import Console
    from rich.table import Table


def summary_table(stats: Stats, title: str = "summary") -> Table:
    from rich.table import Table

    table = Table(title=title, show_header=False, box=None, pad_edge=False)
    table.add_column(style="bold")
    table.add_column(justify="right")
    frac = stats.valid / stats.samples if stats.samples else 0.0
    rows = [
        ("frames", f"{stats.frames}"),
        ("samples", f"{stats.samples}"),
        ("valid", f"{stats.valid} ({100 * frac:.2f} %)"),
        ("degraded (estimator)", f"{stats.degraded}"),
        ("vote failures v1/v2/v3", "/".join(str(v) for v in stats.vote_failures)),
        ("samples lost", f"{stats.samples_lost}"),
        ("CRC errors", f"{stats.crc_errors}"),
        ("wrong DLC", f"{stats.wrong_dlc}"),
        ("unknown IDs", f"{stats.unknown_id}"),
        ("UART link errors", f"{stats.link_errors}"),
        ("log parse errors", f"{stats.parse_errors}"),
        ("time outliers / clock steps", f"{stats.outliers} / {stats.clock_steps}"),
        (
            "gaps ch1/ch2/ch3",
            "/".join(str(c.gaps) for c in stats.channels),
        ),
        (
            "duplicates / late",
            f"{sum(c.duplicates for c in stats.channels)} / {sum(c.late for c in stats.channels)}",
        ),
        ("status-flagged", "/".join(str(c.status_flagged) for c in stats.channels)),
    ]
    if stats.wrap_guesses:  # long gaps bridged on the receive clock alone (pipeline.timeline)
        rows.append(("gap wraps guessed", f"{stats.wrap_guesses}"))
    if stats.socket_drops:  # only a live socketcan bus can say (devices/socketcan_rx.py)
        rows.insert(6, ("dropped by the kernel", f"{stats.socket_drops}"))
    for k, v in rows:
        table.add_row(k, v)
    return table


def print_summary(stats: Stats, title: str = "summary", console: Console | None = None) -> None:
    if console is None:
        from rich.console import Console

        console = Console(stderr=True)
    console.print(summary_table(stats, title))
