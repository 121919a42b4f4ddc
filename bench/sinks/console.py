"""Rich tables that read whole in a pipe, a CI log or a file as on a terminal.

Rich lays a table out to the console's width; without a terminal (``bench fleet | less``,
a CI job's log) that width is 80 columns, and the columns are cut ("fram...") or wrapped.
There the table gets its natural width instead (``COLUMNS`` still wins when set).
"""

from __future__ import annotations

import os
from typing import Any

from rich.console import Console


def print_whole(renderable: Any, *, stderr: bool = False, console: Console | None = None) -> None:
    """Print ``renderable`` (a rich Table, ...) on ``console`` (default: stdout or stderr)."""
    console = console or Console(stderr=stderr)
    if not console.is_terminal and not os.environ.get("COLUMNS"):
        natural = console.measure(renderable, options=console.options.update(max_width=10_000))
        if natural.maximum > console.width:
            console = Console(file=console.file, width=natural.maximum, no_color=console.no_color)
    console.print(renderable)
