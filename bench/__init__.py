"""The gradient bench: pipeline, fusion, logging, replay, acceptance, TUI and CLI."""

__version__ = "0.1.0"
