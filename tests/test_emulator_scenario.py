"""Scenario files: defaults, strict validation naming the key, built-ins, determinism, wraps."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from textwrap import dedent

import numpy as np
import pytest

from bench.errors import ConfigError
from devices.emulator import (
    builtin_scenarios,
    calibration_toml,
    load_scenario,
    parse_scenario,
    simulate,
)
from devices.emulator.scenario import (
    FAULT_PARAMS,
    SCENARIO_DIR,
    BoardModel,
    ChannelModel,
    OdometerModel,
    Scenario,
    VibrationModel,
)
from protocol.records import AdcSample
from tests.helpers import records


def test_defaults_are_nominal_level_standstill_no_faults():
    sc = parse_scenario("", "empty.toml")
    assert [c.angle_deg for c in sc.channels] == [30.0, 0.0, -30.0]
    assert all(c.noise_mps2 == c.bias_mps2 == c.scale_error == 0 for c in sc.channels)
    assert sc.faults == () and sc.track == () and sc.train == ()
    assert (sc.initial_speed_mps, sc.sample_rate_hz, sc.base_id) == (0.0, 200, 0x100)
    tr = simulate(sc).truth
    assert np.all(tr["gradient_permil"] == 0) and np.all(tr["speed_mps"] == 0)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            '[[faults]]\nchannel = 1\nkind = "stuk"\n',
            "bad.toml: faults[1].kind: unknown fault kind 'stuk' (expected one of",
        ),
        ("sample_rate = 100\n", "bad.toml: sample_rate: unknown key"),
        ("sample_rate_hz = 2000\n", "bad.toml: sample_rate_hz: must be <= 1000, got 2000"),
        ("sample_rate_hz = 200.0\n", "bad.toml: sample_rate_hz: expected an integer"),
        ('duration_s = "long"\n', "bad.toml: duration_s: expected a number"),
        ("speed_ref = 1\n", "bad.toml: speed_ref: expected true or false"),
        ("base_id = 0x17F\n", "bad.toml: base_id: 0x17F..0x182 would overlap SPEED_REF"),
        ("[[channels]]\n[[channels]]\n", "bad.toml: channels: expected exactly three"),
        (
            "[[channels]]\nangle_deg = 95\n[[channels]]\n[[channels]]\n",
            "bad.toml: channels[1].angle_deg: must be <= 90",
        ),
        (
            "[[channels]]\nnoise = 1\n[[channels]]\n[[channels]]\n",
            "bad.toml: channels[1].noise: unknown key",
        ),
        ("[[track]]\ngradient_permil = 3\n", "bad.toml: track[1].length_m: missing"),
        ("[[train]]\naccel_mps2 = 1\n", "bad.toml: train[1].duration_s: missing"),
        ("[board]\nlatency = 3\n", "bad.toml: board.latency: unknown key"),
        (
            "[board]\nframe_gap_us = 400\nsample_rate_hz = 1\n",
            "bad.toml: board.sample_rate_hz: unknown key",
        ),
        ("sample_rate_hz = 1000\n[board]\nframe_gap_us = 400\n", "bad.toml: board.frame_gap_us:"),
        ("[odometer]\ndrift_ppm = true\n", "bad.toml: odometer.drift_ppm: expected a number"),
        ('[[faults]]\nkind = "stuck"\n', "bad.toml: faults[1].channel: missing"),
        (
            '[[faults]]\nchannel = 4\nkind = "stuck"\n',
            "bad.toml: faults[1].channel: 4 is not a target",
        ),
        (
            '[[faults]]\nchannel = "uart"\nkind = "stuck"\n',
            "bad.toml: faults[1].channel: 'uart' is not a target",
        ),
        (
            '[[faults]]\nchannel = 1\nkind = "noise"\n',
            "bad.toml: faults[1].channel: 1 is not a target",
        ),
        (
            '[[faults]]\nchannel = 1\nkind = "stuck"\nstart_s = 5\nend_s = 4\n',
            "bad.toml: faults[1].end_s: must be > start_s",
        ),
        (
            '[[faults]]\nchannel = 1\nkind = "stuck"\nstart_s = 61\n',
            "bad.toml: faults[1].start_s: must be < duration_s",
        ),
        (
            '[[faults]]\nchannel = 1\nkind = "crc"\nprobability = 2\n',
            "bad.toml: faults[1].probability: must be <= 1",
        ),
        (
            '[[faults]]\nchannel = 1\nkind = "crc"\ndepth = 2\n',
            "bad.toml: faults[1].depth: unknown key",
        ),
        (
            '[[faults]]\nchannel = 1\nkind = "status"\nbits = ["SELFTST"]\n',
            "bad.toml: faults[1].bits: unknown status bit",
        ),
        (
            '[[faults]]\nchannel = "adc"\nkind = "counter_jump"\njump = 256\n',
            "bad.toml: faults[1].jump: must be <= 255",
        ),
        ("seed = -1\n", "bad.toml: seed: must be >= 0"),
        ("duration_s = 60\n[[faults]]\nchannel = 1\n", "bad.toml: faults[1].kind: missing"),
        ("faults = 3\n", "bad.toml: faults: expected an array of tables"),
        ("seed = \n", "bad.toml: not valid TOML"),
    ],
)
def test_errors_name_the_file_and_key(text, message):
    with pytest.raises(ConfigError) as exc:
        parse_scenario(text, "bad.toml")
    assert str(exc.value).startswith(message), str(exc.value)
    assert "\n" not in str(exc.value)


def test_load_scenario_names_missing_file(tmp_path: Path):
    with pytest.raises(ConfigError, match=r"nope\.toml: no such scenario file"):
        load_scenario(tmp_path / "nope.toml")
    bad = tmp_path / "mine.toml"
    bad.write_text('[[faults]]\nchannel = 3\nkind = "stuk"\n')
    with pytest.raises(
        ConfigError, match=r"^mine\.toml: faults\[1\]\.kind: unknown fault kind 'stuk'"
    ):
        load_scenario(bad)


def test_every_builtin_scenario_loads_and_runs():
    names = builtin_scenarios()
    assert {"example", "demo"} <= set(names)
    for name in names:
        sc = load_scenario(name)
        assert sc.description, f"{name}.toml has no description"
    demo = load_scenario("demo")
    assert 500 <= demo.duration_s <= 700 and len(demo.faults) >= 5
    assert len({f.kind for f in demo.faults}) >= 5
    assert len({tr.gradient_permil for tr in demo.track}) >= 4


def test_example_documents_every_key():
    text = (SCENARIO_DIR / "example.toml").read_text()
    keys = set(
        re.findall(r"^\s*#?\s*([a-z_0-9]+)\s*=", text, re.M)
    )  # optional keys may be commented
    keys |= set(re.findall(r"^\s*\[+([a-z_]+)\]+", text, re.M))
    wanted = {f.name for f in dataclasses.fields(Scenario)} - {"source", "path"}
    for model in (ChannelModel, BoardModel, OdometerModel, VibrationModel):
        wanted |= {f.name for f in dataclasses.fields(model)}
    wanted |= {
        "length_m",
        "gradient_permil",
        "vertical_curve_m",
        "duration_s",
        "accel_mps2",
        "allow_reverse",
        "jerk_mps3",
    }
    wanted |= {"channel", "kind", "start_s", "end_s"}
    for params in FAULT_PARAMS.values():
        wanted |= set(params)
    assert wanted - keys == set()
    kinds = set(re.findall(r'^kind = "([a-z_]+)"', text, re.M))
    assert kinds == set(FAULT_PARAMS)  # one fault of every kind
    sc = load_scenario("example")
    assert len(sc.faults) == len(FAULT_PARAMS)


SEEDED = """
duration_s = 5.0
initial_speed_mps = 3.0
[[channels]]
noise_mps2 = 0.01
[[channels]]
noise_mps2 = 0.01
[[channels]]
noise_mps2 = 0.01
[odometer]
noise_mps = 0.01
[[faults]]
channel = "bus"
kind = "loss"
probability = 0.05
[[faults]]
channel = "uart"
kind = "noise"
probability = 0.05
"""


def test_same_seed_same_frames_bit_for_bit():
    a = simulate(parse_scenario("seed = 9\n" + SEEDED, "a.toml"))
    b = simulate(parse_scenario("seed = 9\n" + SEEDED, "b.toml"))
    assert a.frames.tobytes() == b.frames.tobytes()
    assert a.truth.tobytes() == b.truth.tobytes()
    assert a.uart_bytes() == b.uart_bytes()


def test_different_seed_different_noise():
    a = simulate(parse_scenario("seed = 9\n" + SEEDED, "a.toml"))
    b = simulate(parse_scenario("seed = 10\n" + SEEDED, "b.toml"))
    assert a.truth.tobytes() == b.truth.tobytes()  # the world is the same...

    def codes(s):
        return [r.code for r in records(s.frames[:300]) if isinstance(r, AdcSample)]

    assert codes(a) != codes(b)  # ...the noise is not
    assert a.uart_bytes() != b.uart_bytes()


def test_counter_and_timestamp_wrap():
    sc = parse_scenario(
        "counter0 = 250\nboard_time0_ticks = 65000\nduration_s = 1.0\n", "wrap.toml"
    )
    recs = records(simulate(sc).frames)
    ch1 = [r for r in recs if isinstance(r, AdcSample) and r.channel == 1]
    assert [r.counter for r in ch1[:9]] == [250, 251, 252, 253, 254, 255, 0, 1, 2]
    # 200 Hz = 50 ticks per sample: 65000, 65050, ..., 65500, then 14 (65550 - 65536)
    assert [r.timestamp for r in ch1[9:13]] == [65450, 65500, 14, 64]
    assert all(r.timestamp == (65000 + 50 * k) % 65536 for k, r in enumerate(ch1))
    assert all(r.counter == (250 + k) % 256 for k, r in enumerate(ch1))
    assert simulate(sc).truth["counter"][10] == 260  # unwrapped


def test_start_time_shifts_frames_and_truth_alike():
    a = simulate(parse_scenario("duration_s = 1.0\n", "a.toml"))
    b = simulate(parse_scenario("duration_s = 1.0\nstart_time_s = 1700000000.0\n", "b.toml"))
    assert np.array_equal(
        np.rint(b.frames["t"] * 1e6) - 1700000000 * 10**6, np.rint(a.frames["t"] * 1e6)
    )
    assert b.truth["time_s"][1] == 1700000000.005


def test_seed_override_and_with_changes():
    sc = parse_scenario(dedent(SEEDED), "x.toml")
    assert sc.with_changes(seed=4).seed == 4 and sc.seed == 0


def test_calibration_toml_is_a_bench_config_of_the_board_as_built():
    import tomllib

    from bench.config import config_from_dict

    sc = load_scenario("example")
    cfg = config_from_dict(tomllib.loads(calibration_toml(sc)), "cal.toml")
    assert [c.angle_deg for c in cfg.channels] == [c.angle_deg for c in sc.channels]
    assert (cfg.base_id, cfg.sample_rate_hz, cfg.g) == (sc.base_id, sc.sample_rate_hz, sc.g)
