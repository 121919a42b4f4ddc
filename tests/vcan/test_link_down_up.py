"""The interface goes down and comes back mid-run (``ip link set vcan0 down/up``).

The bench reports the disconnect, retries until the link is up, reports the reconnect and
acquires on; its log stays a valid, complete file. candump (-D: it keeps its socket across
the outage) records the same bus as the witness: outside the window between the disconnect
and the reconnect, the bench has exactly the frames candump has.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from tests.vcan.support import (
    candump,
    first_frame,
    frames_sent,
    log_info,
    need,
    net_admin_missing,
    play,
    read_log_frames,
    replay_csv,
    set_link,
    start_run,
    stop_candump,
    tool_missing,
    topic,
    wire,
)

pytestmark = pytest.mark.vcan

SCENARIO = """
description = "vcan: 10 s at 50 Hz on a 5 permil grade"
seed = 8
duration_s = 10.0
sample_rate_hz = 50
speed_ref = false
initial_speed_mps = 8.0
[[track]]
length_m = 1000.0
gradient_permil = 5.0
"""
TOTAL = 1600  # 10 s x (3 x 50 Hz ADC + 10 Hz status)
"""The ICD's slowest rate: a board in the VM keeps real time beside the bench and candump
(at 360 frames/s it fell seconds behind, and a gap in which the receive clock steps by more
than the timeline's 1 s tolerance is a different test)."""


def test_link_down_and_up_is_a_disconnect_and_a_reconnect_and_the_run_goes_on(tmp_path) -> None:
    need(net_admin_missing() or tool_missing("candump"))
    scenario = tmp_path / "board.toml"
    scenario.write_text(SCENARIO)
    dump = candump(tmp_path)
    run, csv, mcap = start_run(tmp_path, "live")
    board = play(tmp_path, "board", scenario)
    try:
        first_frame()
        time.sleep(3.0)
        set_link("down")
        time.sleep(1.0)
    finally:
        set_link("up")
    assert board.join() == 0, board.text()
    run.wait_settled()
    assert run.stop() == 0, run.text()
    witness = read_log_frames(stop_candump(dump, tmp_path))

    sent, total, errors = frames_sent(board)
    assert total == TOTAL and sent + errors == TOTAL and errors > 0  # the board saw it too
    notices = [n for n in topic(mcap, "/source/notices") if n["kind"] != "info"]
    assert [n["kind"] for n in notices] == ["disconnect", "reconnect"]
    assert "vcan0" in notices[0]["detail"]
    down_t, up_t = notices[0]["t"], notices[1]["t"]
    # the outage on the witness's clock: its longest silence. The bench sees the link go
    # down after the last frame before it (how long after depends on the VM's load)
    before = int(np.argmax(np.diff(witness["t"])))
    assert witness["t"][before] < down_t < up_t < down_t + 10.0

    # the bench has what candump has, but for one gap: what was sent after the link came
    # back and before the bench's new socket was open
    frames = read_log_frames(mcap)
    got, seen = wire(frames), wire(witness)
    k = 0  # the common start
    while k < min(len(got), len(seen)) and got[k] == seen[k]:
        k += 1
    rest = len(got) - k
    assert got[k:] == seen[len(seen) - rest :]
    assert k >= np.count_nonzero(witness["t"] < down_t)  # none lost before the outage
    gap = witness["t"][k : len(seen) - rest]
    # lost only while disconnected (a frame may slip in as the old socket is closed)
    assert all(down_t - 0.05 < gap) and all(gap < up_t + 0.5)
    assert np.count_nonzero(frames["t"] > up_t) > 3 * 160  # seconds of the board after it

    info = log_info(mcap)
    assert info["complete"] and not info["warnings"]
    assert info["events"]["DISCONNECT"] == info["events"]["RECONNECT"] == 1
    assert info["metadata"]["summary"]["frames_logged"] == str(len(frames))
    # the log replays to the live results, samples from both sides of the outage included
    live = csv.read_text()
    assert replay_csv(mcap, tmp_path / "replay.csv") == live
    rows = live.splitlines()[1:]
    assert float(rows[-1].split(",")[0]) > 9.0
