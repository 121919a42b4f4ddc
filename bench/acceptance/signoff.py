"""Who and what an acceptance record is about: the device under test, the station, the
operator, the board as it identified itself, and a sign-off block for the reviewers.

A record a reviewer signs must say which unit was tested (serial number, firmware), where
and by whom; the bench cannot know the serial number (the ACB-3's frames carry none), so
it comes from the plan (``[plan] dut = { serial = ..., firmware = ... }``) or the command
line, and the record says "not given" rather than leave the field out. What the board does
report about itself (its CAN base id, state, sample rate, error counter in BOARD_STATUS) is
stored beside it. Pure data and formatting; no I/O.
"""

from __future__ import annotations

import getpass
import html
import os
import socket
from dataclasses import dataclass, field, replace
from typing import Any

SIGN_OFF_ROLES = ("tested by", "reviewed by", "approved by")
"""The signatures an acceptance record asks for, in order."""

DUT_KEYS = ("serial", "firmware", "hardware")
NOT_GIVEN = "not given"

BOARD_STATES = {0: "BOOT", 1: "RUN", 2: "DEGRADED", 3: "FAULT"}


@dataclass(frozen=True, slots=True)
class Dut:
    """The device under test as the plan or the operator names it."""

    serial: str | None = None
    firmware: str | None = None
    hardware: str | None = None

    def override(self, **values: str | None) -> Dut:
        """Command-line values win over the plan's; None keeps the plan's."""
        return replace(self, **{k: v for k, v in values.items() if v is not None})

    def as_dict(self) -> dict[str, str | None]:
        return {k: getattr(self, k) for k in DUT_KEYS}


def default_operator() -> str:
    """The login name of whoever runs the bench (the record says who pressed the button)."""
    for var in ("BENCH_OPERATOR", "USER", "LOGNAME"):
        if os.environ.get(var):
            return os.environ[var]
    try:
        return getpass.getuser()
    except (KeyError, OSError):  # no passwd entry in a container
        return NOT_GIVEN


def default_station() -> str:
    return os.environ.get("BENCH_STATION") or socket.gethostname() or NOT_GIVEN


def board_identity(base_id: int, last_status: Any, status_frames: int) -> dict[str, Any]:
    """What the board said about itself: the CAN base id its frames used and, from its last
    BOARD_STATUS, state, sample rate and error counter (None where no status arrived)."""
    out: dict[str, Any] = {
        "base_id": f"0x{base_id:03X}",
        "status_frames": int(status_frames),
        "state": None,
        "sample_rate_hz": None,
        "errors": None,
    }
    if last_status is not None and status_frames:
        state = int(last_status["state"])
        out["state"] = BOARD_STATES.get(state, str(state))
        out["sample_rate_hz"] = int(last_status["sample_rate"])
        out["errors"] = int(last_status["errors"])
    return out


@dataclass(frozen=True, slots=True)
class RunContext:
    """Device, station and operator of one acceptance run, and the board as it reported."""

    dut: Dut = field(default_factory=Dut)
    station: str = NOT_GIVEN
    operator: str = NOT_GIVEN
    board: dict[str, Any] | None = None  # board_identity(); None: nothing received

    def with_board(self, board: dict[str, Any] | None) -> RunContext:
        return replace(self, board=board)

    def record(self) -> dict[str, Any]:
        """The record.json blocks ``dut``, ``station``, ``operator`` and ``sign_off``."""
        return {
            "dut": {**self.dut.as_dict(), "board": self.board},
            "station": self.station,
            "operator": self.operator,
            "sign_off": [
                {"role": role, "name": None, "date": None, "signature": None}
                for role in SIGN_OFF_ROLES
            ],
        }

    def junit_properties(self) -> list[tuple[str, str]]:
        props = [(f"dut_{k}", v or NOT_GIVEN) for k, v in self.dut.as_dict().items()]
        if self.board is not None:
            props.append(("dut_board_base_id", self.board["base_id"]))
            if self.board["state"] is not None:
                props.append(("dut_board_state", str(self.board["state"])))
        return [*props, ("station", self.station), ("operator", self.operator)]

    def rows(self) -> list[tuple[str, str]]:
        """(label, text) rows of the device-under-test table, for people."""
        d = self.dut
        rows = [
            ("serial number", d.serial or NOT_GIVEN),
            ("firmware", d.firmware or NOT_GIVEN),
        ]
        if d.hardware:
            rows.append(("hardware", d.hardware))
        b = self.board
        if b is None:
            rows.append(("board (BOARD_STATUS)", "nothing received"))
        elif b["state"] is None:
            rows.append(("board (BOARD_STATUS)", f"base id {b['base_id']}, no status frame"))
        else:
            rows.append(
                (
                    "board (BOARD_STATUS)",
                    f"base id {b['base_id']}, {b['state']}, {b['sample_rate_hz']} Hz, "
                    f"errors {b['errors']} ({b['status_frames']} status frames)",
                )
            )
        rows += [("station", self.station), ("operator", self.operator)]
        return rows


def dut_html(ctx: RunContext) -> str:
    e = html.escape
    rows = "".join(f"<tr><th>{e(k)}</th><td>{e(v)}</td></tr>" for k, v in ctx.rows())
    return f"<h2>Device under test</h2><table class='meta'>{rows}</table>"


def sign_off_html() -> str:
    """Blank lines to sign on paper (or a PDF printed from the browser)."""
    rows = "".join(
        f"<tr><td>{role}</td><td class='blank'></td><td class='blank'></td>"
        "<td class='blank'></td></tr>"
        for role in SIGN_OFF_ROLES
    )
    return (
        "<h2>Sign-off</h2><table class='signoff'><tr><th>role</th><th>name</th>"
        f"<th>date</th><th>signature</th></tr>{rows}</table>"
    )


SIGN_OFF_CSS = (
    "table.signoff td.blank{min-width:12em;height:2.2em;border-bottom:1px solid #333}"
    "table.signoff{margin-bottom:2em}"
)
