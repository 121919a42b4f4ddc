"""Long gaps in the stream (issue 16 item 3, found at a SocketCAN link down/up).

A gap longer than half a board-timestamp wrap (3.2768 s) hides whole 6.5536 s wraps that
only the receive clock can count, and a link that comes back often comes back with a
different receive delay. The wraps must be those the receive-time gap is nearest to (the
sample counter choosing between the two nearest), not the smallest forward step: that put
everything after the gap one wrap back in time, all of it "late", and no results came out.
Expected values are the instants the frames were built from (100 Hz: 100 ticks a sample).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.records.events import EventKind
from protocol.records import RawFrame
from tests.helpers import assemble, instant, kinds, status_frame

RATE = 100
T0 = 1.7e9
WRAP_S = 6.5536
CUTS = [None, 1, 7, 250]


def stream(keep: list[int], shift_from: int, shift_s: float, rate_known: bool) -> list[RawFrame]:
    """The instants ``keep`` at 100 Hz; those from ``shift_from`` on received ``shift_s`` later
    (the receive delay changed across the gap)."""
    frames = [status_frame(RATE, T0)] if rate_known else []
    for k in keep:
        for f in instant(k, rate=RATE, t0=T0):
            frames.append(RawFrame(f.t + shift_s, f.can_id, f.data) if k >= shift_from else f)
    return frames


@pytest.mark.parametrize("shift_s", [0.3, -0.3, 0.9])
@pytest.mark.parametrize("rate_known", [True, False])
@pytest.mark.parametrize("cut", CUTS)
def test_gap_past_half_a_wrap_with_a_delay_change_keeps_the_time_axis(shift_s, rate_known, cut):
    """The reproduction: 10 s at 100 Hz, 2.36 s .. 5.65 s lost (3.29 s > 3.28 s), every
    later frame received 0.3 s later (or earlier). Main put it all one wrap back."""
    keep = [k for k in range(1000) if not 236 <= k < 565]
    samples, events = assemble(stream(keep, 565, shift_s, rate_known), RATE, cut)
    assert samples["n"].tolist() == keep  # 671 samples, the last at 9.99 s
    assert samples["ticks"].tolist() == [100 * k for k in keep]
    assert samples["present"].all()
    assert len(kinds(events, EventKind.LATE)) == 0
    lost = kinds(events, EventKind.SAMPLES_LOST)
    assert lost["n"].tolist() == [236] and lost["value"].tolist() == [329]
    # the counter confirms the wraps the receive clock asks for: nothing was guessed
    assert len(kinds(events, EventKind.WRAP_GUESS)) == 0
    # a delay change under the 1 s receive tolerance is no clock step
    assert len(kinds(events, EventKind.CLOCK_STEP)) == 0
    assert abs(samples["t"][-1] - (T0 + 9.99 + shift_s)) < 1e-3


@pytest.mark.parametrize("shift_s", [0.4, -0.4, 1.5])
@pytest.mark.parametrize("rate_known", [True, False])
@pytest.mark.parametrize("cut", CUTS)
def test_gap_of_two_and_a_half_wraps_with_a_delay_change(shift_s, rate_known, cut):
    """1638 samples lost (16.38 s, 2.4994 wraps): the timestamp step alone is 0.4994 of a
    wrap, the receive-time gap says 2 more. A delay change past the 1 s receive tolerance
    (1.5 s) is also a clock step: the first frame after the gap waits as an outlier, the
    next confirms it."""
    keep = list(range(500)) + list(range(2138, 2438))
    samples, events = assemble(stream(keep, 2138, shift_s, rate_known), RATE, cut)
    assert samples["n"].tolist() == keep
    assert samples["ticks"].tolist() == [100 * k for k in keep]
    assert len(kinds(events, EventKind.LATE)) == 0
    lost = kinds(events, EventKind.SAMPLES_LOST)
    assert lost["n"].tolist() == [500] and lost["value"].tolist() == [1638]
    assert len(kinds(events, EventKind.WRAP_GUESS)) == 0
    present = np.ones((len(keep), 3), dtype=bool)
    if abs(shift_s) > 1.0:
        assert kinds(events, EventKind.CLOCK_STEP)["value"].tolist() == [round(shift_s * 1000)]
        out = kinds(events, EventKind.OUTLIER)
        assert out["n"].tolist() == [2138] and out["channel"].tolist() == [1]
        present[500, 0] = False
    else:
        assert len(kinds(events, EventKind.CLOCK_STEP)) == 0
    assert samples["present"].tolist() == present.tolist()


@pytest.mark.parametrize("rate_known", [True, False])
@pytest.mark.parametrize("cut", CUTS)
def test_gap_without_receive_times_takes_the_shortest_step(rate_known, cut):
    """A raw capture (receive time NaN) has no clock to count wraps: a gap under half a
    wrap is placed by board ticks; one past half a wrap (3.29 s) is taken for the shortest
    step, 0.3236 s back (as on main), so its frames are late and counted, never a guess."""
    short = [k for k in range(600) if not 100 <= k < 400]  # 3.00 s gap
    frames = [RawFrame(float("nan"), f.can_id, f.data) for f in stream(short, 0, 0.0, rate_known)]
    samples, events = assemble(frames, RATE, cut)
    assert samples["n"].tolist() == short
    assert samples["ticks"].tolist() == [100 * k for k in short]
    assert kinds(events, EventKind.SAMPLES_LOST)["value"].tolist() == [300]

    long = [k for k in range(800) if not 236 <= k < 565]
    frames = [RawFrame(float("nan"), f.can_id, f.data) for f in stream(long, 0, 0.0, rate_known)]
    samples, events = assemble(frames, RATE, cut)
    assert len(kinds(events, EventKind.WRAP_GUESS)) == 0
    # 565 lands a wrap early (tick 56500 - 65536 = -9036), long closed: its frames are late
    # until the stream catches up; every frame after the gap is late or in a sample
    before = samples[samples["n"] < 236]
    assert before["n"].tolist() == list(range(236)) and before["present"].all()
    after = samples[samples["n"] >= 236]
    late = kinds(events, EventKind.LATE)
    assert len(late) > 0 and int(after["present"].sum()) + len(late) == 3 * (800 - 565)


@pytest.mark.parametrize(
    ("elapsed_s", "d", "dc", "want"),
    [
        (3.59, 32900 - 65536, 329, (1, False)),  # the reproduction: 0.3 s off whole wraps
        (5.01, 100, 1, (0, False)),  # +5 s host clock step, no gap: the counter says 0 wraps
        (6.5536 * 2 + 0.05, 100, 1, (2, False)),  # whole wraps within 0.2 s: bridged as-is
        (3.59, 32900 - 65536, 7, (1, True)),  # the counter agrees with neither: a guess
        (3.0 + 3.0, 32900 - 65536, 7, (0, False)),  # too far off to guess: no bridge
        (float("nan"), 32900 - 65536, 329, (0, False)),  # no receive time
    ],
)
def test_gap_wraps_against_hand_counted_gaps(elapsed_s, d, dc, want):
    from bench.pipeline.timeline import gap_wraps

    assert gap_wraps(elapsed_s / 1e-4, d, dc, 100.0) == want


def test_replay_of_a_candump_log_with_a_link_down_up(tmp_path: Path, capsys):
    """End to end as found: emulate 10 s at 100 Hz to candump, cut 2.36 .. 5.65 s, receive
    the rest 0.3 s later, replay: 671 result rows to 9.99 s, nothing late."""
    scenario = tmp_path / "s.toml"
    scenario.write_text(
        "seed = 4\nduration_s = 10.0\nsample_rate_hz = 100\ninitial_speed_mps = 4.0\n"
        "[[track]]\nlength_m = 200.0\ngradient_permil = 10.0\n"
        "[[channels]]\n[[channels]]\n[[channels]]\n"
    )
    log = tmp_path / "x.log"
    assert main(["emulate", str(scenario), "--out", str(log), "-q"]) == 0
    lines, t0 = [], None
    for line in log.read_text().splitlines():
        t = float(line.split()[0].strip("()"))
        t0 = t if t0 is None else t0
        if 2.36 <= t - t0 < 5.65:
            continue
        if t - t0 >= 5.65:
            line = f"({t + 0.3:.6f})" + line[line.index(")") + 1 :]
        lines.append(line)
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.csv"
    assert main(["replay", str(log), "--csv", str(out), "-q"]) == 0
    rows = out.read_text().splitlines()
    assert len(rows) == 1 + 671
    assert rows[-1].split(",")[0] == "9.99"
    assert "late" not in capsys.readouterr().err


def test_a_wrap_guess_is_a_counted_notice():
    from bench.pipeline.stats import Stats
    from bench.records.events import describe, make_events, severity

    ev = make_events(EventKind.WRAP_GUESS, np.array([1.0, 2.0]), 2, np.array([10, 20]), 1)
    stats = Stats()
    stats.count_events(ev)
    stats.count_events(ev[:1])  # a live step's few
    assert stats.wrap_guesses == 3 and stats.as_dict()["wrap_guesses"] == 3
    assert severity(EventKind.WRAP_GUESS) == "info"
    assert describe(ev[0]).startswith("WRAP_GUESS ch2 sample 10 1 timestamp wraps")
