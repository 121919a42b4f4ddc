"""Which calibration a command uses: one rule for every source, said out loud.

* ``--config FILE`` always wins (a real board's calibration sheet, or a corrected one).
* An emulated board (``--emulate``, ``bench demo``, an acceptance plan's scenario) is
  calibrated as built: the scenario's true angles, sample rate, base id and g, as a real
  bench would be from the board's calibration sheet. Otherwise every emulated run would show
  a calibration error as if it were a fault (0.2 deg of mounting error is ~3.5 permil).
* A recorded MCAP run replays with the calibration it recorded.
* Anything else (a live bus, a candump/BLF/... log) gets the bench's default calibration
  sheet (``config`` in bench.toml, ``BENCH_CONFIG``, ...: :mod:`bench.defaults`), else the
  ICD's nominal values, and the line printed says so; an emulator ``.log`` gets its board's
  sheet from ``bench emulate --out run.log --calibration-out cal.toml`` and ``--config
  cal.toml``.
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench.config import Config, config_from_dict, load_config


def scenario_config(scenario: Any) -> Config:
    """The calibration of an emulated board as built (a Scenario, or a scenario path/name)."""
    from devices.emulator import calibration_toml, load_scenario

    sc = scenario if hasattr(scenario, "channels") else load_scenario(scenario)
    name = Path(sc.path).name if getattr(sc, "path", None) else sc.source
    return config_from_dict(
        tomllib.loads(calibration_toml(sc)),
        source=f"scenario {name} as built",
        origin="scenario",
    )


def default_config(use_defaults: bool = True) -> Config:
    """What a source without a calibration of its own gets: the bench's default sheet (the
    ``config`` of :mod:`bench.defaults`), else the ICD's nominal values."""
    from bench.defaults import setting

    found = setting("config") if use_defaults else None
    return load_config(found.value) if found is not None else Config()


def live_config(config_path: str | None, emulate: str | Path | None = None) -> Config:
    """The calibration of a live run: ``--config``, else the emulated board as built, else
    the default sheet or nominal."""
    if config_path:
        return load_config(config_path)
    if emulate:
        from devices.emulator.scenario import resolve_scenario_path

        return scenario_config(resolve_scenario_path(emulate))
    return default_config()


def is_mcap(path: str | Path) -> bool:
    return str(path).lower().endswith(".mcap")


def replay_config(config_path: str | None, log: str | Path, *, use_defaults: bool = True) -> Config:
    """The calibration of a replay: ``--config``, else the one an MCAP log recorded, else
    the default sheet (unless ``use_defaults`` is off) or nominal."""
    if config_path:
        return load_config(config_path)
    if is_mcap(log):
        from bench.mcaplog.recorded import recorded_config

        recorded = recorded_config(log)
        if recorded is not None:
            return recorded
    return default_config(use_defaults)


def replay_hint(config: Config, log: str | Path) -> str | None:
    """A note when a log without a recorded calibration is replayed with nominal values."""
    if config.origin != "nominal" or config.recorded_in is not None:
        return None
    what = "the MCAP log records no calibration" if is_mcap(log) else "a log file holds none"
    return (
        f"note: {what}; for an emulator log give --config from "
        "`bench emulate SCENARIO --out FILE --calibration-out cal.toml`, "
        "for a real board its calibration sheet"
    )


def announce(config: Config, say: Callable[[str], None]) -> None:
    """Print the one calibration line (``say`` adds the ``bench:`` prefix and the stream)."""
    say(config.announcement())
