"""Live-source options shared by `bench run`, `bench tui` and `bench accept`.

A live source is a python-can bus, a serial port, or the virtual board running in-process
on python-can's `virtual` bus; all three end up as a devices.base.LiveSource.
"""

from __future__ import annotations

import argparse
import itertools
import os
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench import __version__
from bench.config import Config
from bench.errors import BenchError
from devices.base import LiveSource
from devices.cpu_placement import live_cpu_label, live_cpus

DEFAULT_LOG_DIR = Path("logs")
_emu_ids = itertools.count(1)


@dataclass
class LiveSetup:
    source: LiveSource
    description: str  # for people: "virtual board demo.toml", "socketcan:vcan0", ...
    slug: str  # for file names
    emulator: Any = None  # handle of an in-process virtual board (has .stop(), .done, .frames_sent)
    scenario_path: Path | None = None
    cleanup: list[Callable[[], None]] = field(default_factory=list)
    metadata: dict[str, str] = field(default_factory=dict)  # every recording's run record
    # states these too, e.g. "foxglove": the live stream's address (its port may be chosen)

    def start_board(self) -> None:
        """Start the in-process virtual board, if any: called once the runner listens, so
        that no frame waits in the bus while the run and its log are being set up."""
        begin = getattr(self.emulator, "begin", None)
        if callable(begin):
            begin()

    def close(self) -> None:
        if self.emulator is not None:
            self.emulator.stop()
        self.source.close()
        for fn in self.cleanup:
            fn()


def add_live_arguments(parser: argparse.ArgumentParser, *, emulate_required: bool = False) -> None:
    from bench.mcaplog.foxglove_stream import add_foxglove_arguments
    from devices.cli_args import add_source_arguments

    add_source_arguments(parser)
    parser.add_argument(
        "--emulate",
        metavar="SCENARIO",
        required=emulate_required,
        help="run the virtual board in-process on python-can's virtual bus (scenario TOML)",
    )
    parser.add_argument(
        "--config",
        help="calibration config (TOML); default: the virtual board as built with --emulate, "
        "else the ICD's nominal values",
    )
    add_log_arguments(parser)
    add_foxglove_arguments(parser)


def add_log_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--mcap", metavar="PATH", help="MCAP log file (default: logs/<UTC time>-<source>.mcap)"
    )
    parser.add_argument(
        "--no-log", action="store_true", help="do not write an MCAP log (not recommended)"
    )


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.-]+", "-", text).strip("-")[:40] or "source"


def open_emulator(scenario_path: str | Path, speed: float = 1.0) -> LiveSetup:
    """The virtual board on a private python-can virtual channel, and a source listening to it.
    The board plays once :meth:`LiveSetup.start_board` is called (after the runner starts)."""
    import can

    from devices.bus import CanBusSource
    from devices.emulator import load_scenario, start_virtual_board
    from devices.emulator.scenario import resolve_scenario_path

    path = resolve_scenario_path(scenario_path)  # a file, or a built-in name such as "demo"
    scenario = load_scenario(path)
    channel = f"acb3-emu-{os.getpid()}-{next(_emu_ids)}"
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    source = CanBusSource(bus=bus, owns_bus=True, description=f"virtual board {path.name}")
    handle = start_virtual_board(scenario, channel, speed=speed, start=False)  # start_board()
    return LiveSetup(source, f"virtual board {path.name}", f"emu-{_slug(path.stem)}", handle, path)


def open_live(args: argparse.Namespace) -> LiveSetup:
    """The live source the arguments name; BenchError when there is none or it cannot open."""
    from devices.cli_args import live_source_from_args

    live_cpus()  # a bad BENCH_LIVE_CPU is said before anything opens
    if getattr(args, "emulate", None):
        if getattr(args, "interface", None) or getattr(args, "serial", None):
            raise BenchError("--emulate cannot be combined with --interface/--serial")
        return open_emulator(args.emulate)
    source = live_source_from_args(args)
    if source is None:
        raise BenchError(
            "no source: give --interface/--channel, --serial PORT or --emulate SCENARIO"
        )
    desc = getattr(source, "description", "live source")
    return LiveSetup(source, desc, _slug(desc))


def scenario_file(name: str | Path | None) -> str | Path | None:
    """The file a scenario argument names (a built-in name resolved), for comparing paths."""
    if name is None:
        return None
    from devices.emulator.scenario import resolve_scenario_path

    try:
        return resolve_scenario_path(name)
    except BenchError:
        return name  # reported when the scenario is loaded


def check_live_paths(args: argparse.Namespace, *outputs: tuple[str, str | None]) -> None:
    """A live command's outputs (``--mcap`` unless ``--no-log``, and ``outputs``) against
    its inputs (the scenario, ``--config``) and each other, before anything opens."""
    from devices.paths import check_clashes

    scenario = getattr(args, "emulate", None) or getattr(args, "scenario", None)
    mcap = None if getattr(args, "no_log", False) else getattr(args, "mcap", None)
    check_clashes(
        [
            ("scenario", scenario_file(scenario)),
            ("--config", getattr(args, "config", None)),
            ("--replay log", getattr(args, "replay", None)),
        ],
        [("--mcap", mcap), *outputs],
    )


def default_log_path(slug: str, log_dir: Path | None = None) -> Path:
    """``logs/<UTC time>-<source>.mcap``, in ``log_dir`` or the defaults' log folder."""
    from bench.defaults import log_folder

    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    return (log_dir if log_dir is not None else log_folder()) / f"{stamp}-{slug}.mcap"


def run_metadata(
    setup: LiveSetup, config: Config, extra: dict[str, str] | None = None
) -> dict[str, str]:
    meta = {
        "bench_version": __version__,
        "source": setup.description,
        "config_source": config.source,
        "calibration": config.describe(),
        "config_toml": config.to_toml(),
        "command": " ".join(sys.argv),
        "started_utc": datetime.now(UTC).isoformat(),
        "live_cpu": live_cpu_label(),
    }
    if setup.scenario_path is not None:
        meta["scenario"] = str(setup.scenario_path)
    meta.update(setup.metadata)
    meta.update(extra or {})
    return meta


def open_recording(
    args: argparse.Namespace, setup: LiveSetup, config: Config, *, warn: Callable[[str], None]
) -> Any:
    """The MCAP sink the arguments ask for (None with --no-log, after a loud warning)."""
    if getattr(args, "no_log", False):
        warn("WARNING: --no-log: this run leaves no MCAP record")
        return None
    path = Path(args.mcap) if getattr(args, "mcap", None) else default_log_path(setup.slug)
    return start_recording(path, setup, config)


LOG_WRITER_ENV = "BENCH_LOG_WRITER"
"""``process`` (default): live logs are encoded in a writer process of their own (see
:mod:`bench.mcaplog.writer_process`); ``thread``: in a thread of the bench process."""


def recording_sink_class() -> type:
    """The sink class a live recording uses, as BENCH_LOG_WRITER says."""
    from bench.mcaplog.sink import McapSink
    from bench.mcaplog.writer_process import McapProcessSink

    mode = os.environ.get(LOG_WRITER_ENV, "process").strip().lower() or "process"
    if mode == "thread":
        return McapSink
    if mode == "process":
        return McapProcessSink
    raise BenchError(f"{LOG_WRITER_ENV} must be 'process' or 'thread', got {mode!r}")


def start_recording(path: Path, setup: LiveSetup, config: Config) -> Any:
    sink_class = recording_sink_class()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BenchError(f"cannot create log folder {path.parent}: {exc.strerror or exc}") from None
    from bench.mcaplog.file import check_writable

    if problem := check_writable(path):
        raise BenchError(f"cannot write the MCAP log {path}: {problem}")
    attachments: list[tuple[str, bytes]] = []
    if config.path is not None and Path(config.path).is_file():
        attachments.append((Path(config.path).name, Path(config.path).read_bytes()))
    if setup.scenario_path is not None:
        attachments.append((setup.scenario_path.name, setup.scenario_path.read_bytes()))
    return sink_class(path, config, run_metadata(setup, config), attachments)
