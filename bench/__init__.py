"""The gradient bench: pipeline, fusion, logging, replay, acceptance, TUI and CLI."""

from devices.formats import register_format

__version__ = "0.1.0"

register_format(".mcap", "mcap", "bench.mcaplog.source:open_mcap")  # the bench's recordings
