"""The operator's defaults: which bus, which calibration sheet, which log folder.

A bench machine is wired to one bus and one board; typing ``-i socketcan -c can0 --config
cal/SN-0042.toml`` on every command is how mistakes happen. So the values may come from,
first to last (the first that has a value wins):

1. the command line;
2. ``BENCH_INTERFACE``, ``BENCH_CHANNEL``, ``BENCH_BITRATE``, ``BENCH_CONFIG``, ``BENCH_LOGS``;
3. ``bench.toml`` in the working folder (the bench's own folder);
4. ``$XDG_CONFIG_HOME/bench/config.toml`` (default ``~/.config/bench/config.toml``: the
   operator's);
5. python-can's own configuration (``~/.canrc``, ``can.ini``, ``CAN_INTERFACE`` ...), for the
   bus keys, exactly as ``python -m can.logger`` reads it;
6. the built-in values (logs in ``logs/``; the ICD's nominal calibration).

The files hold flat keys: ``interface``, ``channel``, ``bitrate``, ``config`` (a calibration
sheet) and ``logs`` (the folder live runs log to); relative paths are relative to the file's
folder. An unknown key, a wrong type or a bad value is one ``bench: error:`` line (exit 2).
``bench --print-config`` shows each value and where it came from.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.errors import ConfigError
from devices.textfile import parse_toml, read_text_file
from devices.tomlcheck import is_integer, tname

KEYS = ("interface", "channel", "bitrate", "config", "logs")
BUS_KEYS = ("interface", "channel", "bitrate")
PATH_KEYS = ("config", "logs")
ENV = {key: f"BENCH_{key.upper()}" for key in KEYS}
LOCAL_FILE = "bench.toml"
BUILT_IN: dict[str, Any] = {"logs": Path("logs")}
UNSET = {
    "interface": "not set (a command needs -i, or --emulate/--serial)",
    "channel": "not set",
    "bitrate": "not set (the interface's own)",
    "config": "not set: an emulated board as built, an MCAP's recorded one, else nominal",
    "logs": "not set",
}
BUS_COMMANDS = ("run", "tui", "play")
"""The commands whose bus may come from the defaults (when no other source is given)."""
OTHER_SOURCES = ("emulate", "serial", "replay")
"""Options that pick a source other than a CAN bus: with one of them, no bus defaults."""


@dataclass(frozen=True)
class Setting:
    value: Any
    source: str  # where it came from, as the operator would name it


def user_file(env: Mapping[str, str] | None = None) -> Path:
    env = os.environ if env is None else env
    base = env.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "bench" / "config.toml"


def _checked(key: str, value: Any, where: str, folder: Path | None) -> Any:
    """``value`` as the key's type; ``folder`` anchors relative paths (None: as given)."""
    if key == "bitrate":
        if isinstance(value, str) and value.strip().isdigit():
            value = int(value)
        if not is_integer(value) or value <= 0:
            raise ConfigError(f"{where}: bitrate: expected a positive integer, got {value!r}")
        return int(value)
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}: {key}: expected a non-empty string, got {tname(value)}")
    if key == "interface":
        from devices.cli_args import interface_name

        try:
            return interface_name(value)
        except argparse.ArgumentTypeError as exc:
            raise ConfigError(f"{where}: interface: {exc}") from None
    if key in PATH_KEYS:
        path = Path(value).expanduser()
        return path if folder is None or path.is_absolute() else folder / path
    return value


def _file_layer(path: Path, shown: str) -> dict[str, Setting]:
    """A defaults file's settings ({} when there is none). A FIFO, a device or a folder by
    that name is an error, never read (a FIFO would wait forever) nor passed over unsaid."""
    if not path.exists():
        return {}
    data = parse_toml(read_text_file(path, "defaults"), shown)
    unknown = sorted(set(data) - set(KEYS))
    if unknown:
        raise ConfigError(
            f"{shown}: unknown key {unknown[0]!r} (the defaults file knows {', '.join(KEYS)})"
        )
    return {k: Setting(_checked(k, v, shown, path.parent), shown) for k, v in data.items()}


def _shown(path: Path) -> str:
    home = str(Path.home())
    text = str(path)
    return "~" + text[len(home) :] if home != "/" and text.startswith(home + os.sep) else text


def layers(
    cwd: Path | None = None, env: Mapping[str, str] | None = None
) -> list[dict[str, Setting]]:
    """Environment, working folder's bench.toml, user's config.toml: first wins."""
    env = os.environ if env is None else env
    cwd = Path.cwd() if cwd is None else cwd
    from_env = {
        k: Setting(_checked(k, env[name], name, None), name)
        for k, name in ENV.items()
        if env.get(name, "").strip()
    }
    user = user_file(env)
    return [
        from_env,
        _file_layer(cwd / LOCAL_FILE, f"./{LOCAL_FILE}"),
        _file_layer(user, _shown(user)),
    ]


def resolve(
    given: Mapping[str, Any] | None = None,
    cwd: Path | None = None,
    env: Mapping[str, str] | None = None,
) -> dict[str, Setting | None]:
    """Each key's value and where it came from (None: nothing sets it)."""
    out: dict[str, Setting | None] = {}
    stack = layers(cwd, env)
    for key in KEYS:
        value = (given or {}).get(key)
        setting = Setting(value, "command line") if value is not None else None
        for layer in stack:
            if setting is None and key in layer:
                setting = layer[key]
        if setting is None and key in BUS_KEYS:
            setting = _python_can(key)
        if setting is None and key in BUILT_IN:
            setting = Setting(BUILT_IN[key], "built-in")
        out[key] = setting
    return out


def _python_can(key: str) -> Setting | None:
    import can

    try:
        value = can.util.load_config().get(key)
    except Exception:  # a broken python-can config is python-can's to report, at open
        return None
    if value is None:
        return None
    return Setting(value, "python-can config (~/.canrc, can.ini, CAN_*)")


def setting(key: str) -> Setting | None:
    """The value the defaults (not the command line, not python-can) give ``key``."""
    for layer in layers():
        if key in layer:
            return layer[key]
    return None


def log_folder() -> Path:
    """Where live runs write their MCAP logs unless ``--mcap`` says otherwise."""
    found = setting("logs")
    return Path(found.value) if found is not None else BUILT_IN["logs"]


def apply_bus_defaults(args: argparse.Namespace) -> None:
    """Fill the bus options the command line left out from the defaults, for a command that
    needs a bus and was given no other source (``--emulate``, ``--serial``, ``--replay``).
    python-can's own config still fills what the defaults leave out, when the bus opens."""
    if getattr(args, "command", None) not in BUS_COMMANDS:
        return
    if any(getattr(args, name, None) for name in OTHER_SOURCES):
        return
    for key in BUS_KEYS:
        if getattr(args, key, None) is None and (found := setting(key)) is not None:
            setattr(args, key, found.value)


def print_config(args: argparse.Namespace | None = None) -> None:
    """``bench --print-config``: every key, its value and where it came from."""
    given = {k: getattr(args, k, None) for k in KEYS} if args is not None else {}
    rows = [
        (key, "-" if s is None else str(s.value), UNSET[key] if s is None else s.source)
        for key, s in resolve(given).items()
    ]
    width = max(len(v) for _, v, _ in rows)
    for key, value, source in rows:
        print(f"{key:<10} {value:<{width}}  {source}")
    print(f"(files: ./{LOCAL_FILE}, {_shown(user_file())}; environment: {', '.join(ENV.values())})")
