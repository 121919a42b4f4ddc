"""Each fault kind shows up in the frames as it should.

Frames are checked by decoding them with protocol.can_codec / protocol.uart, and compared
with a twin run of the same scenario without the fault (the noise generators do not
depend on the faults, so the twin differs only where the fault acted).
"""

from __future__ import annotations

from textwrap import dedent

import numpy as np
import pytest

from devices.emulator import parse_scenario, simulate
from protocol.layout import CODE_MAX, CODE_MIN, NOMINAL_SCALE, STATUS_OVR
from protocol.records import AdcSample, BoardStatus
from protocol.uart import deframe_bytes
from tests.helpers import CrcMismatch, records

BASE = """
seed = 21
duration_s = 10.0
sample_rate_hz = 200
initial_speed_mps = 5.0
[[track]]
length_m = 20.0
gradient_permil = 0.0
[[track]]
length_m = 100.0
gradient_permil = 15.0
[[channels]]
noise_mps2 = 0.01
[[channels]]
noise_mps2 = 0.01
[[channels]]
noise_mps2 = 0.01
"""


def fault(channel: int | str, kind: str, **params: object) -> str:
    """One [[faults]] table as TOML (single-quoted strings are TOML literal strings)."""
    lines = ["[[faults]]", f"channel = {channel!r}", f"kind = {kind!r}"]
    return "\n".join(lines + [f"{k} = {v!r}" for k, v in params.items()]) + "\n"


def run(faults: str = "", base: str = BASE):
    return simulate(parse_scenario(dedent(base) + dedent(faults), "faults.toml"))


@pytest.fixture(scope="module")
def twin():
    return run()


def adc_table(sim) -> dict[tuple[int, int], AdcSample]:
    """(channel, sample index) -> decoded ADC record; the sample index from the send time."""
    out = {}
    for f, r in zip(sim.frames, records(sim.frames), strict=True):
        if isinstance(r, AdcSample):
            out[(r.channel, int(f["t"] * 200))] = r  # sent < 5 ms after its instant
    return out


def rows(sim) -> list[tuple[float, int, bytes]]:
    return [(float(f["t"]), int(f["id"]), bytes(f["data"])) for f in sim.frames]


def test_dropout_removes_that_channels_frames_in_the_window(twin):
    sim = run(fault(2, "dropout", start_s=2.0, end_s=4.0))
    t, ids = sim.frames["t"], sim.frames["id"]
    assert not np.any((ids == 0x102) & (t >= 2.0) & (t < 4.0))
    assert np.sum(ids == 0x102) == 2000 - 400
    assert np.sum(ids == 0x101) == np.sum(ids == 0x103) == 2000
    eff = sim.effect(1)
    assert len(eff.removed_uids) == 400 and np.array_equal(eff.samples, np.arange(400, 800))
    assert len(sim.frames) == len(twin.frames) - 400


def test_stuck_freezes_the_code(twin):
    sim = run(fault(3, "stuck", start_s=5.0, end_s=8.0))
    a, b = adc_table(sim), adc_table(twin)
    frozen = b[(3, 999)].code
    assert all(a[(3, k)].code == frozen for k in range(1000, 1600))
    assert len({b[(3, k)].code for k in range(1000, 1600)}) > 100  # it does move normally
    assert all(a[(3, k)] == b[(3, k)] for k in (*range(0, 1000), *range(1600, 2000)))
    assert all(a[(c, k)] == b[(c, k)] for c in (1, 2) for k in range(2000))
    assert len(sim.effect(1).frames) == 600


def test_stuck_at_a_given_code():
    sim = run(fault(1, "stuck", start_s=1.0, end_s=2.0, code=-1234))
    a = adc_table(sim)
    assert {a[(1, k)].code for k in range(200, 400)} == {-1234}


def test_drift_adds_a_ramp(twin):
    sim = run(
        '[[faults]]\nchannel = 1\nkind = "drift"\nstart_s = 2.0\nend_s = 6.0\n'
        "rate_mps2_per_s = 0.05\noffset_mps2 = 0.1\n"
    )
    a, b = adc_table(sim), adc_table(twin)
    for k in range(2000):
        diff = (a[(1, k)].code - b[(1, k)].code) * NOMINAL_SCALE
        t = k / 200
        expected = 0.1 + 0.05 * (t - 2.0) if 2.0 <= t < 6.0 else 0.0
        assert abs(diff - expected) <= 1.01 * NOMINAL_SCALE


def test_spike_hits_exactly_the_reported_samples(twin):
    sim = run(
        '[[faults]]\nchannel = 2\nkind = "spike"\nstart_s = 1.0\nend_s = 9.0\n'
        "amplitude_mps2 = 2.0\nrate_hz = 2.0\nwidth_samples = 2\n"
    )
    a, b = adc_table(sim), adc_table(twin)
    eff = sim.effect(1)
    hit = {k for k in range(2000) if a[(2, k)].code != b[(2, k)].code}
    assert hit == set(eff.samples.tolist()) and len(hit) >= 10
    for k in hit:
        jump = abs(a[(2, k)].code - b[(2, k)].code) * NOMINAL_SCALE
        assert jump == pytest.approx(2.0, abs=2 * NOMINAL_SCALE) or jump == pytest.approx(
            4.0, abs=2 * NOMINAL_SCALE
        )
    assert all(200 <= k < 1800 for k in hit)


@pytest.mark.parametrize(("value", "rail"), [(25.0, CODE_MAX), (-30.0, CODE_MIN)])
def test_saturate_clips_with_ovr(value, rail):
    sim = run(fault(3, "saturate", start_s=3.0, end_s=4.0, value_mps2=value))
    a = adc_table(sim)
    for k in range(2000):
        inside = 600 <= k < 800
        assert (a[(3, k)].code == rail) is inside
        assert bool(a[(3, k)].status & STATUS_OVR) is inside
        assert a[(1, k)].status == a[(2, k)].status == 0
    errors = records(sim.frames[sim.frames["id"] == 0x100])
    assert [r.errors for r in errors][25] == 0 and errors[35].errors == 1  # the board counts it


def test_status_sets_the_bits_and_degrades_the_board():
    sim = run(fault(1, "status", start_s=2.0, end_s=3.0, bits=["CAL", "REF"]))
    a = adc_table(sim)
    for k in range(2000):
        assert a[(1, k)].status == (0x0C if 400 <= k < 600 else 0)
        assert a[(2, k)].status == a[(3, k)].status == 0
    statuses = sim.frames[sim.frames["id"] == 0x100]
    for f, r in zip(statuses, records(statuses), strict=True):
        assert isinstance(r, BoardStatus)
        assert r.state == (2 if 2.0 <= f["t"] < 3.0 else 1)


@pytest.mark.parametrize(("target", "prob"), [("1", 1.0), ('"bus"', 0.3), ('"speed"', 1.0)])
def test_crc_mismatch_exactly_on_the_reported_frames(target, prob):
    sim = run(
        f'[[faults]]\nchannel = {target}\nkind = "crc"\nstart_s = 4.0\nend_s = 5.0\n'
        f"probability = {prob}\n"
    )
    bad = [i for i, r in enumerate(records(sim.frames)) if isinstance(r, CrcMismatch)]
    eff = sim.effect(1)
    assert bad == eff.frames.tolist() and len(bad) > 20
    t = sim.frames["t"][bad]
    assert np.all((t >= 4.0) & (t < 5.0 + 1e-3))
    if target == "1":
        assert set(sim.frames["id"][bad].tolist()) == {0x101} and len(bad) == 200


def test_loss_removes_the_reported_frames_only(twin):
    sim = run(fault("bus", "loss", start_s=2.0, end_s=4.0, probability=0.2))
    eff = sim.effect(1)
    mine, theirs = rows(sim), rows(twin)
    missing = sorted(set(theirs) - set(mine))
    assert set(mine) <= set(theirs)
    assert len(missing) == len(eff.removed_uids) == len(theirs) - len(mine) > 100
    assert all(2.0 <= t < 4.0 + 1e-3 for t, _, _ in missing)
    gone = set(missing)
    assert [r for r in theirs if r not in gone] == mine  # order and times untouched


def test_duplicate_puts_a_copy_right_after_the_original(twin):
    sim = run(fault("adc", "duplicate", start_s=1.0, end_s=2.0, probability=0.5))
    f = sim.frames
    same = (f["id"][1:] == f["id"][:-1]) & np.all(f["data"][1:] == f["data"][:-1], axis=1)
    copies = np.flatnonzero(same) + 1
    assert copies.tolist() == sim.effect(1).frames.tolist() and len(copies) > 100
    assert np.all(f["t"][copies] > f["t"][copies - 1])
    assert np.all((f["id"][copies] >= 0x101) & (f["id"][copies] <= 0x103))
    assert len(f) == len(twin.frames) + len(copies)
    dedup = np.delete(f, copies)
    assert np.array_equal(dedup["id"], twin.frames["id"])
    assert np.array_equal(dedup["data"], twin.frames["data"])


def test_reorder_delays_the_reported_frames_by_depth(twin):
    sim = run(
        '[[faults]]\nchannel = "bus"\nkind = "reorder"\nstart_s = 5.0\nend_s = 6.0\n'
        "probability = 0.1\ndepth = 2\n"
    )
    f, g = sim.frames, twin.frames
    assert np.array_equal(f["t"], g["t"])  # arrival slots unchanged
    moved = sim.effect(1).frames
    assert len(moved) > 20
    key = lambda a: [(int(i), bytes(d)) for i, d in zip(a["id"], a["data"], strict=True)]  # noqa: E731
    mine, theirs = key(f), key(g)
    assert sorted(mine) == sorted(theirs)
    moved_set = {mine[i] for i in moved}
    assert [r for r in mine if r not in moved_set] == [r for r in theirs if r not in moved_set]
    origin = np.array([theirs.index(mine[i]) for i in moved])
    isolated = [
        (i, j) for i, j in zip(moved, origin, strict=True) if np.sum(np.abs(origin - j) <= 3) == 1
    ]
    assert len(isolated) > 10
    assert all(i - j == 2 for i, j in isolated)  # a lone move goes exactly depth places later


def test_counter_jump_jumps_the_counter_not_the_timestamp():
    sim = run(fault("adc", "counter_jump", start_s=3.0, end_s=4.0, jump=-5))
    a = adc_table(sim)
    for k in range(2000):
        want = (k - 5) % 256 if 600 <= k < 800 else k % 256
        assert a[(1, k)].counter == a[(2, k)].counter == a[(3, k)].counter == want
        assert a[(1, k)].timestamp == (50 * k) % 65536
    assert len(sim.effect(1).frames) == 600


def test_counter_jump_on_one_channel_only():
    sim = run(fault(2, "counter_jump", start_s=3.0))
    a = adc_table(sim)
    assert a[(2, 700)].counter == (700 + 17) % 256 and a[(1, 700)].counter == 700 % 256


def test_board_faults_reach_the_uart_but_link_faults_do_not(twin):
    sim = run(
        '[[faults]]\nchannel = 1\nkind = "dropout"\nstart_s = 1.0\nend_s = 2.0\n'
        '[[faults]]\nchannel = "bus"\nkind = "loss"\nprobability = 0.1\n'
        '[[faults]]\nchannel = "bus"\nkind = "duplicate"\nprobability = 0.1\n'
    )
    frames, errors = deframe_bytes(sim.uart_bytes())
    assert errors == []
    board = twin.frames[twin.frames["id"] != 0x180]  # SPEED_REF is the odometer's, not on UART
    keep = ~((board["id"] == 0x101) & (board["t"] >= 1.0) & (board["t"] < 2.0))  # +100 us latency
    assert np.array_equal(frames["id"], board["id"][keep])
    assert np.array_equal(frames["data"], board["data"][keep])


@pytest.mark.parametrize("kind", ["noise", "truncation"])
def test_uart_faults_break_exactly_the_reported_packets(kind, twin):
    extra = "burst_bytes = 6\n" if kind == "noise" else ""
    sim = run(
        f'[[faults]]\nchannel = "uart"\nkind = "{kind}"\nstart_s = 2.0\nend_s = 8.0\n'
        f"probability = 0.05\n{extra}"
    )
    stream = sim.uart_stream()
    frames, errors = deframe_bytes(stream.data)
    clean, clean_errors = deframe_bytes(twin.uart_bytes())
    assert clean_errors == []
    assert stream.packets_broken == len(sim.effect(1).frames) > 50
    assert len(errors) == stream.packets_broken
    assert len(frames) == len(clean) - stream.packets_broken
    good = np.setdiff1d(np.arange(len(clean)), stream.broken)
    assert np.array_equal(frames["data"], clean["data"][good])
    assert np.all((stream.packet_t[stream.broken] >= 2.0) & (stream.packet_t[stream.broken] < 8.0))
    # the stream is CAN frames in the board's send order, one 0x00 per packet
    assert stream.data.count(0) == len(stream) == len(clean)
