"""Sample assembly rules, checked on hand-made frame sequences (ICD 1.1, issue 3)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.pipeline.assembly import Assembler
from bench.records.events import EventKind
from protocol.batch import decode_batch
from protocol.records import RawFrame
from tests.helpers import adc, instant, kinds, pack, status_frame


def assemble(frames: list[RawFrame], chunks: list[int] | None = None, rate: int = 200):
    """Run frames through an Assembler in the given chunk sizes; (samples, events)."""
    arr = pack(frames)
    asm = Assembler(rate)
    outs, evs = [], []
    pos = 0
    sizes = chunks or [len(arr)]
    for size in sizes:
        part = arr[pos : pos + size]
        s, e = asm.push(part["t"], decode_batch(part), pos)
        outs.append(s)
        evs.append(e)
        pos += size
    if pos < len(arr):
        part = arr[pos:]
        s, e = asm.push(part["t"], decode_batch(part), pos)
        outs.append(s)
        evs.append(e)
    s, e = asm.finish()
    outs.append(s)
    evs.append(e)
    return np.concatenate(outs), np.concatenate(evs)


def test_in_order_stream_gives_one_complete_sample_per_instant_across_counter_wrap():
    frames = [f for k in range(10) for f in instant(k, counter0=250)]
    samples, events = assemble(frames)
    assert samples["n"].tolist() == list(range(250, 260))  # unwrapped: 255 -> 256, not 0
    assert samples["present"].all()
    assert samples["code"][0].tolist() == [100, 200, 300]
    assert len(events) == 0


def test_samples_carry_unwrapped_board_time_across_timestamp_wrap():
    frames = [f for k in range(6) for f in instant(k, ts0=65536 - 100)]  # 50 ticks per sample
    samples, _ = assemble(frames)
    assert np.diff(samples["ticks"]).tolist() == [50] * 5


def test_reordered_frame_within_window_joins_its_own_sample():
    frames = [f for k in range(4) for f in instant(k)]
    # ch3 of instant 1 arrives after ch1 of instant 2
    ch3_of_1 = frames.pop(5)
    frames.insert(6, ch3_of_1)
    samples, events = assemble(frames)
    assert samples["n"].tolist() == [0, 1, 2, 3]
    assert samples["present"].all()
    assert len(events) == 0


def test_duplicate_frame_is_counted_and_ignored():
    frames = [f for k in range(3) for f in instant(k)]
    dup = adc(2, 1, 999, 50, 0.0051)  # same channel and counter as instant 1, other code
    frames.insert(5, dup)
    samples, events = assemble(frames)
    assert samples["code"][1].tolist() == [100, 200, 300]  # first frame wins
    d = kinds(events, EventKind.DUPLICATE)
    assert d["channel"].tolist() == [2] and d["n"].tolist() == [1]


def test_missing_channel_proceeds_without_it_once_overdue():
    frames = [f for k in range(5) for f in instant(k)]
    del frames[3 * 2 + 2]  # ch3 of instant 2 lost
    samples, events = assemble(frames)
    assert samples["n"].tolist() == [0, 1, 2, 3, 4]
    assert samples["present"][2].tolist() == [True, True, False]
    gaps = kinds(events, EventKind.GAP)
    assert gaps["channel"].tolist() == [3] and gaps["n"].tolist() == [2]


def test_crc_corrupt_frame_is_an_error_event_and_leaves_the_channel_out():
    frames = [f for k in range(4) for f in instant(k)]
    bad = frames[3 * 1 + 2]
    frames[3 * 1 + 2] = RawFrame(bad.t, bad.can_id, bad.data[:7] + bytes([bad.data[7] ^ 0x55]))
    samples, events = assemble(frames)
    assert samples["present"][1].tolist() == [True, True, False]
    crc = kinds(events, EventKind.CRC_ERROR)
    assert crc["channel"].tolist() == [3] and crc["value"].tolist() == [0x103]


def test_frame_after_its_window_is_late_and_not_merged():
    frames = [f for k in range(6) for f in instant(k)]
    ch2_of_0 = frames.pop(1)
    frames.insert(3 * 3, ch2_of_0)  # arrives when instant 3 starts: sample 0 already closed
    samples, events = assemble(frames)
    assert samples["present"][0].tolist() == [True, False, True]
    late = kinds(events, EventKind.LATE)
    assert late["channel"].tolist() == [2] and late["n"].tolist() == [0]


def test_status_flagged_channel_is_present_but_reported():
    frames = [f for k in range(3) for f in instant(k)]
    f = frames[4]
    frames[4] = adc(2, 1, 200, 50, f.t, status=0x01)
    samples, events = assemble(frames)
    assert samples["status"][1].tolist() == [0, 1, 0]
    flag = kinds(events, EventKind.STATUS_FLAG)
    assert flag["channel"].tolist() == [2] and flag["value"].tolist() == [1]


def test_long_gap_beyond_counter_range_is_unwrapped_from_board_time():
    # 1000 samples (5 s at 200 Hz) missing: the counter alone would alias (1000 mod 256 = 232)
    frames = [f for k in (0, 1, 2, 1002, 1003, 1004) for f in instant(k)]
    samples, events = assemble(frames)
    assert samples["n"].tolist() == [0, 1, 2, 1002, 1003, 1004]
    lost = kinds(events, EventKind.SAMPLES_LOST)
    assert lost["n"].tolist() == [3] and lost["value"].tolist() == [999]


def test_gap_longer_than_timestamp_wrap_uses_receive_time():
    # 20 s gap: the 16-bit board timestamp wraps three times; receive time resolves it
    k2 = 4000
    frames = [f for k in (0, 1, 2, k2, k2 + 1) for f in instant(k)]
    samples, _ = assemble(frames)
    assert samples["n"].tolist() == [0, 1, 2, k2, k2 + 1]
    assert samples["ticks"][3] - samples["ticks"][0] == k2 * 50


def test_counter_jump_against_board_time_is_reported_when_rate_known():
    frames = [status_frame(200, 0.0)] + [f for k in range(3) for f in instant(k)]
    frames += [adc(ch, 3 + 40, 1, 3 * 50, 3 / 200 + ch * 1e-4) for ch in (1, 2, 3)]
    samples, events = assemble(frames)
    jumps = kinds(events, EventKind.COUNTER_JUMP)
    assert jumps["value"].tolist() == [40, 40, 40]
    assert samples["n"].tolist() == [0, 1, 2, 3]  # board time places them


def test_one_channel_counter_off_does_not_pull_the_others_apart():
    """A counter fault on ch1 alone: ch2 and ch3 must still make complete samples."""
    frames = [status_frame(200, 0.0)]
    for k in range(10):
        f = instant(k)
        if 3 <= k < 7:
            f[0] = adc(1, k + 5, 100, k * 50, f[0].t)  # ch1 counter 5 ahead, timestamp right
        frames += f
    samples, events = assemble(frames)
    assert samples["n"].tolist() == list(range(10))
    assert samples["present"].all()
    jumps = kinds(events, EventKind.COUNTER_JUMP)
    assert jumps["channel"].tolist() == [1] * 4 and jumps["value"].tolist() == [5] * 4
    assert len(kinds(events, EventKind.LATE)) == 0


def test_unknown_id_and_wrong_dlc_are_events():
    frames = [*instant(0), RawFrame(0.001, 0x7FF, b"\x00" * 8), RawFrame(0.002, 0x101, b"\x01\x02")]
    _, events = assemble(frames)
    assert kinds(events, EventKind.UNKNOWN_ID)["value"].tolist() == [0x7FF]
    assert kinds(events, EventKind.WRONG_DLC)["value"].tolist() == [2]


# -- chunk independence: the live (frame by frame) and replay (big batch) paths agree -----

fault = st.sampled_from(
    ["ok", "ok", "ok", "drop", "dup", "swap", "crc", "flag", "late", "jitter", "t_off", "ts_off"]
)


@st.composite
def faulty_stream(draw):
    n = draw(st.integers(5, 60))
    # with a status frame the board time places frames; without, the counter leads
    frames: list[RawFrame] = [status_frame(200, 0.0)] if draw(st.booleans()) else []
    for k in range(n):
        frames += instant(k, codes=(k, 2 * k, 3 * k), counter0=240)
    out: list[RawFrame] = []
    clock = 0.0
    held: list[tuple[int, RawFrame]] = []  # (frames to wait, frame): arrives after its window
    for f in frames:
        what = draw(fault)
        for i, (wait, g) in enumerate(held):
            held[i] = (wait - 1, g)
        out += [g for wait, g in held if wait <= 0]
        held = [(wait, g) for wait, g in held if wait > 0]
        if what == "drop":
            continue
        if what == "late":
            held.append((draw(st.integers(7, 12)), f))
            continue
        if what == "crc":
            f = RawFrame(f.t, f.can_id, f.data[:7] + bytes([f.data[7] ^ 1]))
        if what == "flag" and f.can_id != 0x100:
            flagged = bytearray(f.data)
            flagged[4] = 0x04
            f = adc(f.can_id - 0x100, flagged[0], 0, flagged[5] | flagged[6] << 8, f.t, status=4)
        if what == "jitter" and f.can_id != 0x100:  # board time off by < half a period
            d = f.data
            ts = (d[5] | d[6] << 8) + draw(st.integers(-20, 20))
            f = adc(f.can_id - 0x100, d[0], d[1] | d[2] << 8 | d[3] << 16, ts, f.t, d[4])
        if what == "ts_off" and f.can_id != 0x100:  # a wild board time (bench.pipeline.timeline)
            d = f.data
            ts = (d[5] | d[6] << 8) + draw(st.sampled_from([-30000, 5000, 30000]))
            f = adc(f.can_id - 0x100, d[0], d[1] | d[2] << 8 | d[3] << 16, ts, f.t, d[4])
        if what == "t_off":  # a wild receive time
            f = RawFrame(
                f.t + draw(st.sampled_from([-7.5, 3.0, 1e15, float("nan")])), f.can_id, f.data
            )
        f = RawFrame(f.t + clock, f.can_id, f.data)
        if draw(st.integers(0, 40)) == 0:  # the host clock steps from here on
            clock += draw(st.sampled_from([5.0, -5.0, 3000.0]))
        out.append(f)
        if what == "dup":
            out.append(f)
        if what == "swap" and len(out) >= 2:
            out[-1], out[-2] = out[-2], out[-1]
    out += [g for _, g in held]
    # live-sized cuts mixed with longer ones
    size = st.one_of(st.integers(1, 7), st.integers(65, 94))
    cuts = draw(st.lists(size, min_size=1, max_size=40))
    return out, cuts


@settings(max_examples=80, deadline=None)
@given(faulty_stream())
def test_any_batching_gives_identical_samples_and_events(data):
    frames, cuts = data
    one_s, one_e = assemble(frames)
    by1_s, by1_e = assemble(frames, [1] * len(frames))
    cut_s, cut_e = assemble(frames, cuts)
    assert one_s.tobytes() == by1_s.tobytes() == cut_s.tobytes()
    key = lambda e: sorted(map(tuple, e[["kind", "channel", "n", "value"]].tolist()))  # noqa: E731
    assert key(one_e) == key(by1_e) == key(cut_e)
    # output is in sample order with no sample emitted twice
    assert np.all(np.diff(one_s["n"]) > 0)


def test_one_absurd_receive_time_costs_nothing():
    """Receive time only bridges plausible gaps; 0, negative or 1e15 s are ignored for it."""
    good = [f for k in range(20) for f in instant(k, t0=1.7e9)]
    for bad_t in (1e15, -1.0, 0.0, float("nan")):
        frames = list(good)
        f = frames[30]
        frames[30] = RawFrame(bad_t, f.can_id, f.data)
        samples, events = assemble(frames)
        assert samples["n"].tolist() == list(range(20)), bad_t
        assert samples["present"].all()
        assert len(kinds(events, EventKind.SAMPLES_LOST)) == 0
