"""User-facing errors: the CLI prints them as one line and exits non-zero, never a traceback."""

from __future__ import annotations


class BenchError(Exception):
    """An error the operator can act on (bad file, bad key, missing device)."""

    exit_code = 2


class ConfigError(BenchError):
    """A config, scenario or plan file is malformed; the message names the file and key."""
