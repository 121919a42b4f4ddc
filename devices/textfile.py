"""Reading an operator's text file (config, scenario, plan) with one-line errors."""

from __future__ import annotations

from pathlib import Path

from devices.errors import ConfigError


def read_text_file(path: Path, what: str) -> str:
    """The file's UTF-8 text; ConfigError naming the file when it is missing or not text."""
    try:
        return path.read_text(encoding="utf-8")
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
