"""Reading an operator's text file (config, scenario, plan) with one-line errors."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from devices.errors import ConfigError
from devices.paths import regular_file_problem

MAX_NESTING = 32
"""Deepest nesting of arrays and tables an operator's TOML may have (ours need 3)."""


def read_text_file(path: Path, what: str) -> str:
    """The file's UTF-8 text; ConfigError naming the file when it is missing, not a regular
    file (a FIFO or /dev/zero would be read forever) or not text."""
    why = regular_file_problem(path)
    if why.startswith("not a regular file") or why == "it is a folder":
        raise ConfigError(f"{path}: cannot read {what}: {why}")
    try:
        return path.read_text(encoding="utf-8-sig")  # an editor's byte-order mark is fine
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text {what} (byte {exc.start})") from None


def path_or_packaged(name: str | Path, folder: Path) -> Path | None:
    """``name`` as given if that file exists, else the packaged ``folder/<name>.toml`` for a
    bare name (``demo`` -> demo.toml); None when neither exists."""
    p = Path(name)
    if p.exists():
        return p
    packaged = folder / (p.name if p.suffix == ".toml" else f"{p.name}.toml")
    if p.parent == Path(".") and packaged.exists():
        return packaged
    return None


def _depth(value: Any, limit: int) -> int:
    """Nesting depth of parsed TOML, counted iteratively and only up to ``limit + 1``."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict | list):
            if d + 1 > limit:
                return d + 1
            deepest = max(deepest, d + 1)
            stack.extend((x, d + 1) for x in (v.values() if isinstance(v, dict) else v))
    return deepest


def parse_toml(text: str, file: str) -> dict[str, Any]:
    """Parsed TOML text; ConfigError naming ``file`` when it is not TOML or nests arrays or
    tables deeper than MAX_NESTING (tomllib itself recurses: thousands of '[' exhaust the
    stack)."""
    text = text.removeprefix("\ufeff")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{file}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(
            f"{file}: arrays or tables nested too deep (at most {MAX_NESTING} levels)"
        ) from None
    if _depth(data, MAX_NESTING) > MAX_NESTING:
        raise ConfigError(
            f"{file}: arrays or tables nested too deep (at most {MAX_NESTING} levels)"
        )
    return data
