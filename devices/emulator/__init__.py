"""The virtual ACB-3 board: scenario -> frames (CAN and UART), truth and fault record.

    sim = simulate(load_scenario("demo"))
    sim.frames        # FRAME_DTYPE, send order, t = whole microseconds / 1e6
    sim.truth         # TRUTH_DTYPE per sampling instant
    sim.effects       # what each [[faults]] entry did
    sim.uart_bytes()  # the UART byte stream with UART faults

Players put a simulation on a python-can bus, a pseudo-terminal or a file; see
:mod:`devices.emulator.player` and docs/EMULATOR.md.
"""

from devices.emulator.engine import TRUTH_COLUMNS, TRUTH_DTYPE
from devices.emulator.player import (
    CanPlayer,
    PtyPlayer,
    start_virtual_board,
    write_truth_csv,
)
from devices.emulator.scenario import (
    FAULT_KINDS,
    Fault,
    Scenario,
    builtin_scenarios,
    calibration_toml,
    load_scenario,
    parse_scenario,
    scenario_from_dict,
)
from devices.emulator.simulation import Simulation, UartStream, simulate
from devices.emulator.stream import ODOMETER_TRUTH_DTYPE, FaultEffect

__all__ = [
    "FAULT_KINDS",
    "ODOMETER_TRUTH_DTYPE",
    "TRUTH_COLUMNS",
    "TRUTH_DTYPE",
    "CanPlayer",
    "Fault",
    "FaultEffect",
    "PtyPlayer",
    "Scenario",
    "Simulation",
    "UartStream",
    "builtin_scenarios",
    "calibration_toml",
    "load_scenario",
    "parse_scenario",
    "scenario_from_dict",
    "simulate",
    "start_virtual_board",
    "write_truth_csv",
]
