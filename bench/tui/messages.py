"""Typed messages between the snapshot poller (a worker thread) and the App."""

from __future__ import annotations

from rich.text import Text
from textual.message import Message

from bench.live.view import Snapshot


class SnapshotReady(Message):
    """A snapshot was taken and the plot drawn off the UI thread (None: not redrawn)."""

    def __init__(
        self, snapshot: Snapshot, plot: Text | None, rates: list[float], source: object = None
    ) -> None:
        super().__init__()
        self.snapshot = snapshot
        self.plot = plot
        self.rates = rates
        self.source = source  # the session it came from (a replay restart replaces it)


class SessionStopped(Message):
    """The runner has stopped and every sink is closed (the MCAP file is final)."""

    def __init__(self, error: str | None) -> None:
        super().__init__()
        self.error = error
