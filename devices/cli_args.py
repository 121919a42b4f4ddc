"""Command-line options that pick a live source, shared by every ``bench`` subcommand.

The CAN options mirror ``python -m can.logger`` (-i/-c/-b, same meaning and help), so an
operator's habits and python-can config files carry over; ``--serial`` selects the
board's UART instead.
"""

from __future__ import annotations

import argparse
import difflib
from typing import Any

import can

from devices.base import LiveSource
from devices.bus import CanBusSource
from devices.errors import BenchError
from devices.serial_port import DEFAULT_BAUD, SerialSource

INTERFACES = sorted(can.VALID_INTERFACES)
"""Every interface python-can knows, its plugins included: the operator chooses."""


def interface_name(text: str) -> str:
    """``--interface``: a name python-can knows; a typo is one line naming the valid ones."""
    if text in can.VALID_INTERFACES:
        return text
    close = difflib.get_close_matches(text, INTERFACES, n=1)
    hint = f"did you mean {close[0]}? " if close else ""
    raise argparse.ArgumentTypeError(
        f"unknown interface {text!r} ({hint}python-can knows {', '.join(INTERFACES)})"
    )


interface_name.__name__ = "interface"


def add_interface_argument(parser: Any, help: str) -> None:
    """``-i/--interface``: python-can's names, checked by :func:`interface_name`; the choices
    are there for shell completion (bench --completion)."""
    parser.add_argument(
        "-i",
        "--interface",
        type=interface_name,
        choices=INTERFACES,
        default=None,
        metavar="INTERFACE",
        help=help,
    )


def add_source_arguments(parser: argparse.ArgumentParser) -> argparse._ArgumentGroup:
    """Add the live-source options to ``parser`` (in their own help group) and return it."""
    group = parser.add_argument_group(
        "live source",
        "A CAN bus (values not given come from python-can's config file ~/.canrc or can.ini "
        "and the CAN_INTERFACE / CAN_CHANNEL / CAN_BITRATE environment variables) or the "
        "board's UART (--serial).",
    )
    add_interface_argument(
        group,
        "Specify the backend CAN interface to use (e.g. socketcan, pcan, kvaser, slcan, "
        "virtual). If left blank, fall back to reading from configuration files.",
    )
    group.add_argument(
        "-c",
        "--channel",
        default=None,
        metavar="CHANNEL",
        help="Most backend interfaces require some sort of channel. For example with the "
        'serial interface the channel might be a rfcomm device: "/dev/rfcomm0". With the '
        'socketcan interface valid channel examples include: "can0", "vcan0".',
    )
    group.add_argument(
        "-b",
        "--bitrate",
        type=int,
        default=None,
        metavar="BITRATE",
        help="Bitrate to use for the CAN bus (the board uses 500000).",
    )
    group.add_argument(
        "--serial",
        default=None,
        metavar="PORT",
        help="Read the board's UART on this serial port (e.g. /dev/ttyUSB0, "
        "/dev/serial/by-id/..., COM3) instead of a CAN bus.",
    )
    group.add_argument(
        "--baud",
        type=int,
        default=None,
        metavar="BAUD",
        help=f"UART baud rate for --serial (default {DEFAULT_BAUD}, 8N1).",
    )
    return group


def live_source_from_args(args: argparse.Namespace) -> LiveSource | None:
    """The live source the options ask for, or None when none of them was given."""
    interface = getattr(args, "interface", None)
    channel = getattr(args, "channel", None)
    bitrate = getattr(args, "bitrate", None)
    port = getattr(args, "serial", None)
    baud = getattr(args, "baud", None)
    can_given = [
        name
        for name, value in (
            ("--interface", interface),
            ("--channel", channel),
            ("--bitrate", bitrate),
        )
        if value is not None
    ]
    if port is not None and can_given:
        raise BenchError(f"--serial cannot be combined with {'/'.join(can_given)}")
    if baud is not None and port is None:
        raise BenchError("--baud needs --serial")
    if bitrate is not None and bitrate <= 0:
        raise BenchError(f"--bitrate must be positive, not {bitrate}")
    if baud is not None and baud <= 0:
        raise BenchError(f"--baud must be positive, not {baud}")
    if port is not None:
        if not port.strip():
            raise BenchError("--serial needs a port name")
        return SerialSource(port, baud or DEFAULT_BAUD)
    if can_given:
        return CanBusSource(interface, channel, bitrate)
    return None
