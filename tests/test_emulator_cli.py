"""`bench emulate` end to end, and the real-time players (python-can virtual bus, pty)."""

from __future__ import annotations

import csv
import os
import select
import time
from pathlib import Path

import can
import numpy as np
import pytest

from bench.cli import main
from bench.errors import BenchError
from devices.emulator import (
    CanPlayer,
    PtyPlayer,
    load_scenario,
    simulate,
    start_virtual_board,
)
from devices.emulator.stream_out import write_streamed
from protocol.uart import deframe_bytes

SHORT = """
seed = 4
duration_s = 2.0
sample_rate_hz = 100
initial_speed_mps = 4.0
[[track]]
length_m = 3.0
gradient_permil = 0.0
[[track]]
length_m = 100.0
gradient_permil = 30.0
[[channels]]
noise_mps2 = 0.01
[[channels]]
[[channels]]
[[faults]]
channel = 2
kind = "crc"
start_s = 1.0
end_s = 1.2
[[faults]]
channel = "uart"
kind = "truncation"
probability = 0.05
"""


@pytest.fixture
def scenario(tmp_path: Path) -> Path:
    p = tmp_path / "short.toml"
    p.write_text(SHORT)
    return p


def test_emulate_to_candump_log_and_truth_csv(scenario: Path, tmp_path: Path, capsys):
    log, truth = tmp_path / "x.log", tmp_path / "t.csv"
    assert main(["emulate", str(scenario), "--out", str(log), "--truth", str(truth)]) == 0
    sim = simulate(load_scenario(scenario))
    msgs = list(can.LogReader(str(log)))
    assert len(msgs) == len(sim.frames)
    assert [m.arbitration_id for m in msgs] == sim.frames["id"].tolist()
    assert [bytes(m.data) for m in msgs] == [bytes(d) for d in sim.frames["data"]]
    assert [m.timestamp for m in msgs] == sim.frames["t"].tolist()  # bit-identical floats
    with truth.open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == [
        "time_s",
        "counter",
        "gradient_permil",
        "accel_mps2",
        "speed_mps",
        "position_m",
        "body_pitch_deg",
    ]
    assert len(rows) == 1 + len(sim.truth) == 201
    last = [float(v) for v in rows[-1]]
    assert last[0] == 1.99 and last[1] == 199 and last[2] == pytest.approx(30.0)
    assert last[4] == 4.0 and last[5] == pytest.approx(4.0 * 1.99)
    out = capsys.readouterr().out
    assert "wrote" in out and "crc ch2" in out


def test_emulate_to_uart_bin(scenario: Path, tmp_path: Path):
    out = tmp_path / "x.bin"
    assert main(["emulate", str(scenario), "--out", str(out), "-q"]) == 0
    sim = simulate(load_scenario(scenario))
    frames, errors = deframe_bytes(out.read_bytes())
    stream = sim.uart_stream()
    assert stream.packets_broken > 0 and len(errors) == stream.packets_broken
    assert len(frames) + len(errors) == int(np.sum(sim.frames["id"] != 0x180))


def test_bad_scenario_is_one_line_and_exit_2(tmp_path: Path, capsys):
    bad = tmp_path / "scenario.toml"
    bad.write_text('[[faults]]\nchannel = 3\nkind = "stuk"\n[[faults]]\n')
    assert main(["emulate", str(bad), "--out", str(tmp_path / "x.log")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("bench: error: scenario.toml: faults[1].kind: unknown fault kind 'stuk'")
    assert "\n" not in err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "x.txt"], "unknown output type '.txt'"),
        (["--out", "x.log", "--pty"], "--out writes a file"),
        ([], "nothing to do"),
        (["--pty", "--speed", "0"], "--speed must be a positive number"),
    ],
)
def test_bad_arguments_exit_2(scenario: Path, tmp_path: Path, capsys, argv, message):
    argv = [str(tmp_path / a) if a.startswith("x.") else a for a in argv]
    assert main(["emulate", str(scenario), *argv]) == 2
    assert message in capsys.readouterr().err


def test_mcap_output_is_written_by_the_bench(scenario: Path, tmp_path: Path, capsys):
    assert main(["emulate", str(scenario), "--out", str(tmp_path / "x.mcap")]) == 0
    assert (tmp_path / "x.mcap").read_bytes()[:8] == b"\x89MCAP0\r\n"
    with pytest.raises(BenchError, match="mcap output needs"):
        write_streamed(load_scenario(scenario), tmp_path / "y.mcap")


def test_list_builtin_scenarios(capsys):
    assert main(["emulate", "--list"]) == 0
    out = capsys.readouterr().out
    assert "demo" in out and "example" in out


def test_emulate_realtime_on_a_virtual_bus(scenario: Path, capsys):
    assert (
        main(["emulate", str(scenario), "-i", "virtual", "-c", "emu-cli-test", "--speed", "20"])
        == 0
    )
    sim = simulate(load_scenario(scenario))
    assert f"done: {len(sim.frames)} of {len(sim.frames)} frames sent" in capsys.readouterr().out


def test_virtual_board_in_process(scenario: Path):
    channel = f"emu-test-{os.getpid()}"
    rx = can.Bus(interface="virtual", channel=channel)
    try:
        handle = start_virtual_board(scenario, channel, speed=10.0)
        got = []
        deadline = time.monotonic() + 120.0  # a hang guard, not a bound
        while time.monotonic() < deadline and not (handle.done and rx_empty(rx, got)):
            msg = rx.recv(0.05)
            if msg is not None:
                got.append(msg)
        sim = handle.simulation
        assert handle.done and handle.error is None
        assert handle.frames_sent == len(sim.frames) == len(got)
        assert [m.arbitration_id for m in got] == sim.frames["id"].tolist()
        assert [bytes(m.data) for m in got] == [bytes(d) for d in sim.frames["data"]]
        handle.stop()  # harmless after the end
    finally:
        rx.shutdown()


def rx_empty(rx: can.BusABC, got: list) -> bool:
    msg = rx.recv(0.0)
    if msg is None:
        return True
    got.append(msg)
    return False


def test_virtual_board_stops_cleanly_midway():
    sc = load_scenario("demo")
    handle = start_virtual_board(sc.with_changes(duration_s=30.0), f"emu-stop-{os.getpid()}")
    time.sleep(0.3)
    handle.stop()  # joins the player thread
    assert handle.done and 0 < handle.frames_sent < len(handle.simulation.frames)
    assert handle.error is None


class FlakyBus:
    """A bus whose every third send fails, as a bus-off or a full TX queue would."""

    def __init__(self) -> None:
        self.calls = 0
        self.sent: list[can.Message] = []
        self.closed = False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.calls += 1
        if self.calls % 3 == 0:
            raise can.CanOperationError("Transmit buffer full")
        self.sent.append(msg)

    def shutdown(self) -> None:
        self.closed = True


def test_can_player_counts_bus_errors_and_goes_on(scenario: Path):
    sim = simulate(load_scenario(scenario))
    bus = FlakyBus()
    player = CanPlayer(sim, bus, speed=20.0)
    player.start()
    assert player.wait(5.0) and player.error is None
    assert player.errors == len(sim.frames) // 3 and "buffer full" in player.last_error
    assert player.frames_sent == len(bus.sent) == len(sim.frames) - player.errors
    assert bus.closed


def test_pty_player_streams_the_uart_bytes(scenario: Path):
    sim = simulate(load_scenario(scenario))
    stream = sim.uart_stream()
    player = PtyPlayer(stream, sim.t0, speed=10.0)
    fd = os.open(player.slave_path, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        player.start()
        data = bytearray()
        deadline = time.monotonic() + 120.0  # a hang guard, not a bound
        while time.monotonic() < deadline and len(data) < len(stream.data):
            if select.select([fd], [], [], 0.1)[0]:
                data += os.read(fd, 65536)
        assert player.wait(60.0)  # a hang guard
        assert (len(data), player.bytes_discarded, player.packets_written) == (
            len(stream.data),
            0,
            len(stream),
        )
        assert bytes(data) == stream.data
        assert player.packets_written == len(stream) and player.bytes_discarded == 0
    finally:
        player.stop()
        os.close(fd)
