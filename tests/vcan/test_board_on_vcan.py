"""The virtual board and the bench on one SocketCAN bus, with candump recording beside them.

One live session (module fixture) on vcan0: ``bench run -i socketcan -c vcan0`` listening,
``candump -l vcan0`` recording, ``bench emulate SCENARIO -i socketcan -c vcan0`` playing a
6 s scenario at 100 Hz. Expected counts come from the ICD's rates, not from the code:
BOARD_STATUS at 10 Hz, SPEED_REF at 50 Hz, one ADC frame per channel per sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.vcan.support import (
    Bench,
    assert_same_results,
    bench_main,
    candump,
    columns_without,
    frames_sent,
    log_info,
    need,
    per_id,
    play,
    read_log_frames,
    replay_csv,
    start_run,
    stop_candump,
    tool_missing,
    topic,
    wire,
)

pytestmark = pytest.mark.vcan

SCENARIO = """
description = "vcan: 6 s at 100 Hz, accelerating onto an 8 permil grade"
seed = 5
duration_s = 6.0
sample_rate_hz = 100
initial_speed_mps = 5.0
[[train]]
duration_s = 3.0
accel_mps2 = 0.5
[[track]]
length_m = 10.0
gradient_permil = 0.0
[[track]]
length_m = 200.0
gradient_permil = 8.0
[[channels]]
angle_deg = 30.1
noise_mps2 = 0.001
[[channels]]
angle_deg = 0.2
noise_mps2 = 0.001
[[channels]]
angle_deg = -29.9
noise_mps2 = 0.001
"""
EXPECTED_PER_ID = {0x100: 60, 0x101: 600, 0x102: 600, 0x103: 600, 0x180: 300}


@dataclass
class Session:
    folder: Path
    emulator_log: Path  # `bench emulate --out`: the same scenario, written as fast as possible
    board: Bench
    run: Bench
    run_code: int
    csv: Path
    mcap: Path
    candump_log: Path


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Session:
    tmp = tmp_path_factory.mktemp("board")
    scenario = tmp / "board.toml"
    scenario.write_text(SCENARIO)
    emulator_log = tmp / "emulated.log"
    assert bench_main("emulate", scenario, "--out", emulator_log, "-q") == 0
    dump_dir = tmp / "candump"
    dump_dir.mkdir()
    need(tool_missing("candump"))
    dump = candump(dump_dir)
    run, csv, mcap = start_run(tmp, "live")
    board = play(tmp, "board", scenario)
    assert board.join() == 0, board.text()
    run.wait_received(2160)
    run_code = run.stop()
    return Session(tmp, emulator_log, board, run, run_code, csv, mcap, stop_candump(dump, dump_dir))


def test_every_frame_sent_is_received_and_logged_per_id(session: Session) -> None:
    expected = read_log_frames(session.emulator_log)
    assert dict(per_id(expected)) == EXPECTED_PER_ID
    assert frames_sent(session.board) == (2160, 2160, 0)
    assert session.run_code == 0, session.run.text()
    logged = read_log_frames(session.mcap)
    assert wire(logged) == wire(expected)  # every frame, in order, byte for byte
    info = log_info(session.mcap)
    assert info["complete"] and not info["warnings"]
    assert info["frames_by_id"] == {f"0x{k:X}": n for k, n in EXPECTED_PER_ID.items()}
    assert info["frames_by_outcome"] == {"OK": 2160}
    summary = info["metadata"]["summary"]
    assert (summary["frames"], summary["frames_logged"]) == ("2160", "2160")
    assert summary["dropped_frames"] == "0"
    kinds = [n["kind"] for n in topic(session.mcap, "/source/notices")]
    assert "overflow" not in kinds and "disconnect" not in kinds
    # what candump saw on the same bus at the same time
    assert dict(per_id(read_log_frames(session.candump_log))) == EXPECTED_PER_ID


def test_live_csv_equals_the_replay_of_the_emulators_own_log(session: Session) -> None:
    live = session.csv.read_text()
    assert len(live.splitlines()) == 1 + 600
    emulated = replay_csv(session.emulator_log, session.folder / "emulated.csv")
    assert_same_results(live, emulated)
    utc = [r[1] for r in columns_without(live)[1:]]
    assert all(u.endswith("Z") for u in utc)  # the live run's kernel receive times


def test_candump_log_replayed_gives_the_results_of_the_bench_mcap(session: Session) -> None:
    from_candump = replay_csv(session.candump_log, session.folder / "candump.csv")
    from_mcap = replay_csv(session.mcap, session.folder / "mcap.csv")
    assert len(from_candump.splitlines()) == 1 + 600
    assert from_mcap == session.csv.read_text()
    assert_same_results(from_candump, from_mcap)
