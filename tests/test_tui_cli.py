"""`bench tui` and `bench demo` on the command line: options, refusals, the packaged demo."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from bench.cli import main
from bench.commands.demo import DEMO_SCENARIO, scenario_config


def test_tui_and_demo_are_commands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["tui", "--help"])
    out = capsys.readouterr().out
    for opt in ("--replay", "--speed", "--paused", "--interface", "--serial", "--emulate"):
        assert opt in out
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    assert "--scenario" in capsys.readouterr().out


def test_replay_refuses_a_live_source_too(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tui", "--replay", "x.log", "--emulate", "demo"]) == 2
    assert "--replay cannot be combined with --emulate" in capsys.readouterr().err


def test_replay_of_a_missing_log_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tui", "--replay", "no/such/file.log"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench: error:") and "no/such/file.log" in err


def test_demo_scenario_is_packaged_and_calibrated_as_built() -> None:
    assert DEMO_SCENARIO.is_file()
    assert DEMO_SCENARIO.parent == Path(__import__("devices").__file__).parent / "scenarios"
    built = tomllib.loads(DEMO_SCENARIO.read_text())["channels"]
    config = scenario_config(DEMO_SCENARIO)
    assert [c.angle_deg for c in config.channels] == [c["angle_deg"] for c in built]
