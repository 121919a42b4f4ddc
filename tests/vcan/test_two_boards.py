"""Two boards and foreign traffic on one bus: each bench fuses its own board, logs everything.

Board A at BASE 0x100 sends SPEED_REF (the train's one odometer, 0x180, ICD 1); board B at
BASE 0x200 (a second board, ICD 1) does not. Beside them cangen sends foreign frames: a
standard 0x555 and an extended 0x18FEF101, whose low 11 bits are board A's ch1 ID. Bench A
(default config) and bench B (``base_id = 0x200``) listen to the same vcan0.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest

from protocol.records import FLAG_EXTENDED
from tests.vcan.support import (
    Bench,
    assert_same_results,
    bench_main,
    cangen,
    frames_sent,
    log_info,
    need,
    play,
    read_log_frames,
    replay_csv,
    start_run,
    tool_missing,
    wire,
)

pytestmark = pytest.mark.vcan

BOARD = """
seed = {seed}
duration_s = 6.0
sample_rate_hz = 100
base_id = {base}
speed_ref = {speed_ref}
initial_speed_mps = 4.0
vertical_curve_accel = true  # the car feels the curve at 5 m (the estimator reads curves in w)
[[train]]
duration_s = 2.0
accel_mps2 = 0.3
[[track]]
length_m = 5.0
gradient_permil = {grade_0}
[[track]]
length_m = 200.0
gradient_permil = {grade_1}
[[channels]]
angle_deg = 30.0
noise_mps2 = 0.001
[[channels]]
angle_deg = 0.0
noise_mps2 = 0.001
[[channels]]
angle_deg = -30.0
noise_mps2 = 0.001
"""
A = {0x100: 60, 0x101: 600, 0x102: 600, 0x103: 600, 0x180: 300}  # 10 Hz, 100 Hz x 3, 50 Hz
B = {0x200: 60, 0x201: 600, 0x202: 600, 0x203: 600}
FOREIGN = {0x555: 150, 0x18FEF101: 100}
ON_BUS = {**A, **B, **FOREIGN}
SPEED_COLUMNS = ("gradient_signed_permil", "a_ref_mps2")
"""Bench B's estimator takes board A's SPEED_REF where it overlaps board B's samples, which
depends on when the two boards happened to start: these columns are not compared."""


@dataclass
class TwoBoards:
    folder: Path
    logs: dict[str, Path]  # each board's own `bench emulate --out` log
    boards: dict[str, Bench]
    runs: dict[str, Bench]
    codes: dict[str, int]
    csv: dict[str, Path]
    mcap: dict[str, Path]
    config_b: Path


@pytest.fixture(scope="module")
def two(tmp_path_factory: pytest.TempPathFactory) -> TwoBoards:
    need(tool_missing("cangen"))
    tmp = tmp_path_factory.mktemp("two")
    scenarios = {
        "a": BOARD.format(seed=1, base="0x100", speed_ref="true", grade_0=0.0, grade_1=6.0),
        "b": BOARD.format(seed=2, base="0x200", speed_ref="false", grade_0=-3.0, grade_1=-9.0),
    }
    paths, logs = {}, {}
    for name, text in scenarios.items():
        paths[name] = tmp / f"board_{name}.toml"
        paths[name].write_text(text)
        logs[name] = tmp / f"board_{name}.log"
        assert bench_main("emulate", paths[name], "--out", logs[name], "-q") == 0
    config_b = tmp / "bench_b.toml"
    config_b.write_text("[board]\nbase_id = 0x200\n")
    run_a, csv_a, mcap_a = start_run(tmp, "bench_a")
    run_b, csv_b, mcap_b = start_run(tmp, "bench_b", "--config", config_b)
    boards = {name: play(tmp, f"board_{name}", paths[name]) for name in paths}
    foreign = [
        cangen("-I", "555", "-L", "8", "-D", "i", "-g", "20", "-n", "150"),
        cangen("-e", "-I", "18FEF101", "-L", "8", "-D", "r", "-g", "30", "-n", "100"),
    ]
    assert [p.wait(120) for p in foreign] == [0, 0]
    for board in boards.values():
        assert board.join() == 0, board.text()
    run_a.wait_received(sum(ON_BUS.values()))
    run_b.wait_received(sum(ON_BUS.values()))
    codes = {"a": run_a.stop(), "b": run_b.stop()}
    return TwoBoards(
        tmp,
        logs,
        boards,
        {"a": run_a, "b": run_b},
        codes,
        {"a": csv_a, "b": csv_b},
        {"a": mcap_a, "b": mcap_b},
        config_b,
    )


def _kinds(frames) -> Counter[tuple[int, bool]]:
    ext = (frames["flags"] & FLAG_EXTENDED) != 0
    return Counter(zip(frames["id"].tolist(), ext.tolist(), strict=True))


def test_both_benches_log_every_frame_on_the_bus(two: TwoBoards) -> None:
    assert frames_sent(two.boards["a"]) == (2160, 2160, 0)
    assert frames_sent(two.boards["b"]) == (1860, 1860, 0)
    expected = {(i, i > 0x7FF): n for i, n in ON_BUS.items()}
    logged = {}
    for name in "ab":
        assert two.codes[name] == 0, two.runs[name].text()
        logged[name] = read_log_frames(two.mcap[name])
        assert dict(_kinds(logged[name])) == expected
        info = log_info(two.mcap[name])
        assert info["complete"] and not info["warnings"]
        summary = info["metadata"]["summary"]
        assert summary["frames"] == summary["frames_logged"] == str(sum(ON_BUS.values()))
    # one bus: each sender's frames in one order for both. Frames of different senders may
    # interleave differently per socket: a multi-CPU kernel hands vcan frames to the
    # receivers from each sending CPU's own queue, in parallel
    for can_id in ON_BUS:
        mine = [logged[name][logged[name]["id"] == can_id] for name in "ab"]
        assert wire(mine[0]) == wire(mine[1]), hex(can_id)


def test_each_bench_takes_only_its_own_board_and_the_odometer(two: TwoBoards) -> None:
    own = {"a": A, "b": {**B, 0x180: A[0x180]}}
    for name in "ab":
        outcomes = log_info(two.mcap[name])["frames_by_outcome"]
        ok = sum(own[name].values())
        assert outcomes == {"OK": ok, "UNKNOWN_ID": sum(ON_BUS.values()) - ok}


def test_board_a_is_fused_as_if_alone_on_the_bus(two: TwoBoards) -> None:
    alone = replay_csv(two.logs["a"], two.folder / "alone_a.csv")
    assert len(alone.splitlines()) == 1 + 600
    live = two.csv["a"].read_text()
    assert_same_results(live, alone)


def test_board_b_is_fused_as_if_alone_but_for_the_shared_odometer(two: TwoBoards) -> None:
    alone = replay_csv(two.logs["b"], two.folder / "alone_b.csv", two.config_b)
    live = two.csv["b"].read_text()
    assert len(live.splitlines()) == len(alone.splitlines()) == 1 + 600
    assert_same_results(live, alone, *SPEED_COLUMNS)
