"""The shared live-source options: parsing, the source they build, and bad combinations."""

from __future__ import annotations

import argparse
import os
import uuid
from pathlib import Path

import can
import pytest

from bench.errors import BenchError
from devices.bus import CanBusSource
from devices.cli_args import add_source_arguments, live_source_from_args
from devices.serial_port import DEFAULT_BAUD, SerialSource


@pytest.fixture(autouse=True)
def no_python_can_config(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for var in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(can.util, "CONFIG_FILES", [str(tmp_path / ".canrc")])


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="bench test")
    add_source_arguments(parser)
    return parser.parse_args(argv)


def test_nothing_given_is_no_live_source() -> None:
    args = parse([])
    assert (args.interface, args.channel, args.bitrate, args.serial, args.baud) == (None,) * 5
    assert live_source_from_args(args) is None
    assert live_source_from_args(argparse.Namespace()) is None


def test_can_options_build_a_can_bus_source() -> None:
    channel = f"cli-{uuid.uuid4()}"
    src = live_source_from_args(parse(["-i", "virtual", "-c", channel, "-b", "500000"]))
    try:
        assert isinstance(src, CanBusSource)
        assert src.description == f"can bus interface=virtual channel={channel} bitrate=500000"
    finally:
        src.close()


@pytest.mark.skipif(os.name != "posix", reason="needs a pty")
def test_serial_option_builds_a_serial_source() -> None:
    master, slave = os.openpty()
    try:
        src = live_source_from_args(parse(["--serial", os.ttyname(slave)]))
        assert isinstance(src, SerialSource) and src.baudrate == DEFAULT_BAUD
        src.close()
        src = live_source_from_args(parse(["--serial", os.ttyname(slave), "--baud", "115200"]))
        assert src.baudrate == 115200
        src.close()
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["--serial", "/dev/ttyX", "-i", "virtual"],
            "--serial cannot be combined with --interface",
        ),
        (["--serial", "/dev/ttyX", "-b", "500000"], "--serial cannot be combined with --bitrate"),
        (["--baud", "115200"], "--baud needs --serial"),
        (["-i", "virtual", "-c", "x", "-b", "-5"], "--bitrate must be positive"),
        (["--serial", "/dev/ttyX", "--baud", "0"], "--baud must be positive"),
        (["--serial", " "], "--serial needs a port name"),
        (["-b", "500000"], "no interface"),  # nothing in the (empty) python-can config
    ],
)
def test_bad_combinations_are_one_line_bench_errors(argv: list[str], message: str) -> None:
    with pytest.raises(BenchError) as e:
        live_source_from_args(parse(argv))
    assert message in str(e.value) and "\n" not in str(e.value)


def test_every_interface_python_can_knows_is_offered() -> None:
    # parsing only: no bus is built (a udp_multicast bus would send on the IP network)
    assert "udp_multicast" in can.VALID_INTERFACES  # the interface the README's promise covers
    for name in sorted(can.VALID_INTERFACES):
        assert parse(["-i", name, "-c", "239.74.163.2"]).interface == name


def test_udp_multicast_passes_every_bench_command_parser(monkeypatch: pytest.MonkeyPatch) -> None:
    from bench.cli import build_parser

    def must_not_build(*args: object, **kwargs: object) -> None:
        raise AssertionError("a bus was built")

    monkeypatch.setattr(can, "Bus", must_not_build)
    parser = build_parser()
    for command in ("run", "tui", "accept"):
        args = parser.parse_args([command, "-i", "udp_multicast", "-c", "239.74.163.2"])
        assert (args.interface, args.channel) == ("udp_multicast", "239.74.163.2")
    args = parser.parse_args(["emulate", "demo", "-i", "udp_multicast", "-c", "239.74.163.2"])
    assert args.interface == "udp_multicast"


def test_an_interface_python_can_does_not_know_is_refused_by_argparse(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as e:
        parse(["-i", "no-such-interface"])
    assert e.value.code == 2 and "unknown interface 'no-such-interface'" in capsys.readouterr().err


@pytest.mark.parametrize("command", [["run"], ["tui"], ["accept", "level"], ["emulate", "demo"]])
def test_a_wrong_interface_name_is_one_line_naming_the_valid_ones(
    command: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 28: one line, not a usage block; the closest name offered, every name listed."""
    from bench.cli import main

    with pytest.raises(SystemExit) as e:
        main([*command, "-i", "socketcn", "-c", "vcan0"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "usage" not in err
    assert err.startswith(f"bench {command[0]}: error: argument -i/--interface: unknown interface")
    assert "did you mean socketcan?" in err
    assert all(name in err for name in can.VALID_INTERFACES)
