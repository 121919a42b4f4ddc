"""Reading an operator's text file (config, scenario, plan) with one-line errors."""

from __future__ import annotations

from pathlib import Path

from bench.errors import ConfigError


def read_text_file(path: Path, what: str) -> str:
    """The file's UTF-8 text; ConfigError naming the file when it is missing or not text."""
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text {what} (byte {exc.start})") from None
