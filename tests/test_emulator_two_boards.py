"""Two boards on one bus sharing one odometer (issue 25; ICD 1: each board at its own BASE,
one SPEED_REF 0x180 from the train's odometer), played on python-can's ``virtual`` bus.

Board A (0x100) and board B (0x200, 20 m ahead along the train) ride one train at 10 m/s
over a sharp grade change at 60 m: A meets it at 6.0 s, B at (60 - 20) / 10 = 4.0 s, and a
0 deg channel then reads g sin(atan(0.020)) = 0.19609 m/s^2."""

from __future__ import annotations

import math
import time
from textwrap import dedent

import can
import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate, start_virtual_board
from devices.emulator.two_boards import board_b, simulate_bus
from devices.errors import ConfigError
from protocol.layout import G0, NOMINAL_SCALE
from protocol.records import AdcSample
from tests.helpers import records

TWO = """
seed = 4
duration_s = 12.0
sample_rate_hz = 100
initial_speed_mps = 10.0
vertical_curve_m = 0.0
vertical_curve_accel = false
body_modes.enabled = false
[body_pitch]
enabled = false
[standstill]
enabled = false
[[track]]
length_m = 60.0
gradient_permil = 0.0
[[track]]
length_m = 1000.0
gradient_permil = 20.0
[second_board]
base_id = 0x200
offset_m = 20.0
[[second_board.channels]]
angle_deg = 30.0
noise_mps2 = 0.0
[[second_board.channels]]
angle_deg = 0.0
[[second_board.channels]]
angle_deg = -30.0
"""
ON_GRADE = G0 * math.sin(math.atan(0.020))  # 0.19609 m/s^2


def ch2(frames: np.ndarray, base: int) -> tuple[np.ndarray, np.ndarray]:
    """(send time, acceleration) of a board's ch2 (0 deg) frames."""
    mine = frames[frames["id"] == base + 2]
    recs = records(mine, base)
    assert all(isinstance(rec, AdcSample) for rec in recs)
    return mine["t"].astype(float), np.array([rec.code for rec in recs]) * NOMINAL_SCALE


@pytest.fixture(scope="module")
def run():
    return simulate_bus(parse_scenario(dedent(TWO), "two.toml"))


def test_both_boards_ride_one_train_each_at_its_place(run):
    for base, meets in ((0x100, 6.0), (0x200, 4.0)):
        t, a = ch2(run.frames, base)
        assert np.abs(a[t < meets - 0.02]).max() <= NOMINAL_SCALE, hex(base)
        assert np.abs(a[t > meets + 0.02] - ON_GRADE).max() <= NOMINAL_SCALE, hex(base)
    # the second board's truth is the same train 20 m ahead
    a_truth, b_truth = (s.truth for s in run.boards)
    assert np.array_equal(b_truth["position_m"], a_truth["position_m"] + 20.0)
    assert np.array_equal(b_truth["speed_mps"], a_truth["speed_mps"])


def test_one_odometer_and_one_serialised_bus(run):
    ids = set(run.frames["id"].tolist())
    assert ids == {0x100, 0x101, 0x102, 0x103, 0x180, 0x200, 0x201, 0x202, 0x203}
    a, b = run.boards
    n_speed = 12 * 50  # SPEED_REF at 50 Hz, from board A's odometer alone
    assert int(np.sum(run.frames["id"] == 0x180)) == n_speed
    assert int(np.sum(a.frames["id"] == 0x180)) == n_speed and not np.any(b.frames["id"] == 0x180)
    assert len(run.frames) == len(a.frames) + len(b.frames)  # 4320 + 3720
    us = np.rint(run.frames["t"] * 1e6).astype(np.int64)
    assert np.diff(us).min() >= 250  # one frame at a time (frame_gap_us 250)
    # each board's own payloads, in its own order, only delayed while the bus is busy
    for sim in run.boards:
        own = np.isin(run.frames["id"], np.unique(sim.frames["id"]))
        assert run.frames["data"][own].tobytes() == sim.frames["data"].tobytes()
        late = run.frames["t"][own] - sim.frames["t"]
        # at most behind the other board's triple, STATUS and SPEED_REF of one instant
        assert late.min() >= 0.0 and late.max() <= 5 * 250e-6 + 1e-9


def test_the_first_board_alone_is_the_scenario_without_the_second(run):
    alone = simulate(parse_scenario(dedent(TWO).split("[second_board]")[0], "one.toml"))
    assert alone.frames.tobytes() == run.boards[0].frames.tobytes()
    sc = parse_scenario(dedent(TWO), "two.toml")
    assert board_b(sc).seed == 5 and board_b(sc.with_changes(seed=9)).seed == 10


def test_played_on_a_virtual_bus_a_listener_hears_both_boards(run):
    channel = f"two-boards-{time.monotonic_ns()}"
    listener = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    try:
        player = start_virtual_board(parse_scenario(dedent(TWO), "two.toml"), channel, speed=20.0)
        got: list[can.Message] = []
        deadline = time.monotonic() + 120.0  # a hang guard, not a bound
        while len(got) < len(run.frames) and time.monotonic() < deadline:
            msg = listener.recv(timeout=1.0)
            if msg is not None:
                got.append(msg)
        player.stop()
    finally:
        listener.shutdown()
    assert player.errors == 0
    assert [m.arbitration_id for m in got] == run.frames["id"].tolist()
    assert b"".join(bytes(m.data) for m in got) == run.frames["data"].tobytes()


@pytest.mark.parametrize(
    ("keys", "message"),
    [
        ("[second_board]\noffset_m = 1.0\n", "base_id"),  # required
        ("[second_board]\nbase_id = 0x102\n", "overlaps"),
        ("[second_board]\nbase_id = 0x17E\n", "SPEED_REF"),
        ("sample_rate_hz = 1000\n[second_board]\nbase_id = 0x200\n", "bus"),
        ("[second_board]\nbase_id = 0x200\nbogus = 1\n", "bogus"),
    ],
)
def test_bad_second_boards_are_config_errors(keys: str, message: str):
    with pytest.raises(ConfigError, match=message):
        parse_scenario(keys, "bad.toml")


def test_bench_emulate_writes_both_boards_and_each_ones_sheet(tmp_path, capsys):
    from bench.cli import main

    scenario = tmp_path / "two.toml"
    scenario.write_text(dedent(TWO))
    log, cal = tmp_path / "two.log", tmp_path / "cal.toml"
    assert main(["emulate", str(scenario), "--out", str(log), "--calibration-out", str(cal)]) == 0
    ids = [int(line.split()[2].split("#")[0], 16) for line in log.read_text().splitlines()]
    assert (ids.count(0x180), ids.count(0x101), ids.count(0x201)) == (600, 1200, 1200)
    assert "base_id = 0x100" in cal.read_text()
    assert "base_id = 0x200" in (tmp_path / "cal-b.toml").read_text()
    assert "one bus: 8040 frames of two boards" in capsys.readouterr().out
    for argv, message in (
        (["--out", str(tmp_path / "x.mcap")], "candump .log"),
        (["--pty"], "share a CAN bus"),
    ):
        assert main(["emulate", str(scenario), *argv]) == 2
        assert message in capsys.readouterr().err
