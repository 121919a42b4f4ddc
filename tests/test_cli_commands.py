"""The `bench` command tree: built whole for --help, completion and mistakes, and of the one
command being run otherwise (bench.cli imports only that command's module)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from bench.cli import build_parser, command_names, main, named_command
from tests.helpers import bench

COMMANDS = [
    "accept",
    "calibrate",
    "demo",
    "emulate",
    "fleet",
    "log",
    "play",
    "replay",
    "run",
    "tui",
]
"""Every `bench` command (README, 'Commands')."""


def _choices(parser: object) -> dict[str, object]:
    sub = next(a for a in parser._actions if a.dest == "command")  # type: ignore[attr-defined]
    return dict(sub.choices)


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    listed = [line.split()[0] for line in out.splitlines() if line.startswith("    ")]
    assert [name for name in listed if name in COMMANDS] == COMMANDS


def test_the_whole_tree_holds_every_command() -> None:
    assert sorted(_choices(build_parser())) == COMMANDS


@pytest.mark.parametrize("name", COMMANDS)
def test_one_command_alone_parses_as_in_the_whole_tree(name: str) -> None:
    # each command's module registers the command of its own name, and nothing else
    assert name in command_names()
    alone = _choices(build_parser(name))
    assert list(alone) == [name]
    whole = _choices(build_parser())
    assert alone[name].format_help() == whole[name].format_help()  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("argv", "command"),
    [
        (["replay", "x.log", "--csv", "o.csv"], "replay"),
        (["--print-config", "run", "-i", "virtual"], "run"),
        (["log", "info", "x.mcap"], "log"),
        ([], None),
        (["--help"], None),
        (["-h", "replay"], None),
        (["--completion", "bash"], None),
        (["--print-c", "run"], None),  # an abbreviation: argparse's business, whole tree
        (["replai", "x.log"], None),  # a typo: argparse names every choice
    ],
)
def test_the_command_named(argv: list[str], command: str | None) -> None:
    assert named_command(argv) == command


def test_a_typo_names_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["replai", "x.log"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1
    assert err.startswith("bench: error: argument COMMAND: invalid choice: 'replai'")
    for name in COMMANDS:
        assert f"'{name}'" in err


def test_a_helper_module_is_no_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["argtypes"])  # a module of bench.commands without a command
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("bench: error: argument COMMAND: invalid choice: 'argtypes'")
    assert "'replay'" in err


def test_a_command_error_is_still_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["replay"])
    assert e.value.code == 2
    assert capsys.readouterr().err == (
        "bench replay: error: the following arguments are required: input "
        "(see bench replay --help)\n"
    )


def test_print_config_before_a_command_still_works(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--print-config", "replay", "x.log"]) == 0
    assert capsys.readouterr().out.strip()


def test_replay_imports_no_other_command_nor_python_can(tmp_path: Path) -> None:
    log = tmp_path / "board.log"
    log.write_text("(0.000000) can0 123#0011\n(0.001000) can0 123#2233\n")
    code = textwrap.dedent(
        f"""
        import sys
        from bench.cli import main
        main(["replay", {str(log)!r}, "-q"])
        print(sorted(m for m in sys.modules if m.startswith("bench.commands.") or m == "can"))
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "['bench.commands.replay']"


def test_the_program_exits_with_mains_code_its_objects_frozen_for_the_exit(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import gc

    from bench.cli import program

    monkeypatch.setattr(sys, "argv", ["bench", "replay", str(tmp_path / "missing.log")])
    try:
        assert program() == 2
        assert gc.get_freeze_count() > 0  # the exit's collection has nothing left to walk
    finally:
        gc.unfreeze()
    err = capsys.readouterr().err
    assert err.startswith("bench: error: ") and "missing.log" in err and err.count("\n") == 1


def test_python_dash_m_bench_is_the_program(tmp_path: Path) -> None:
    done = bench("replay", str(tmp_path / "missing.log"))
    assert done.returncode == 2
    assert done.stderr.startswith("bench: error: ") and done.stderr.count("\n") == 1
