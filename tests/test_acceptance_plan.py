"""Plan files: strict validation (one line naming file and key), the shipped library, TOML out."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from bench.acceptance.answers import load_answers, parse_answer, schedule_steps
from bench.acceptance.plan import (
    PLAN_DIR,
    dump_toml,
    load_plan,
    parse_plan,
    resolve_plan_path,
    shipped_plans,
)
from bench.errors import ConfigError
from devices.emulator import scenario_from_dict

GOOD = """
[plan]
title = "t"
expect = "pass"

[scenario]
duration_s = 10.0
initial_speed_mps = 10.0
[[scenario.track]]
length_m = 1000.0
gradient_permil = 20.0
[[scenario.faults]]
channel = 3
kind = "dropout"
start_s = 5.0
end_s = 6.0

[[checks]]
name = "steady"
kind = "gradient_error"
from_s = 1.0
to_s = 5.0
max_permil = 0.5
[[checks]]
kind = "fault_detected"
channel = 3
within_samples = 10
"""


def test_good_plan_parses() -> None:
    plan = parse_plan(GOOD, "good.toml")
    assert plan.name == "plan" and plan.expect == "pass" and plan.emulated
    assert [c.name for c in plan.checks] == ["steady", "fault_detected #2"]
    steady = plan.checks[0]
    assert (steady.from_s, steady.to_s, steady.get("max_permil")) == (1.0, 5.0, 0.5)
    assert steady.get("estimator") == "reference"  # the default
    assert plan.config().sample_rate_hz == 200


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('title = "t"', 'title = "t"\ncolour = 1', "bad.toml: plan.colour: unknown key"),
        ("max_permil = 0.5", "max_permil = 0.5\nmax_permill = 1", "checks[1].max_permill: unknown"),
        ("max_permil = 0.5", 'max_permil = "0.5"', "checks[1].max_permil: expected a number"),
        ("max_permil = 0.5", "max_permil = -1.0", "checks[1].max_permil: must be >= 0"),
        ("max_permil = 0.5", "", "checks[1].max_permil: missing"),
        ('kind = "gradient_error"', 'kind = "gradient_eror"', "checks[1].kind: unknown check kind"),
        ("to_s = 5.0", "to_s = 0.5", "checks[1].to_s: must be > from_s"),
        ("max_permil = 0.5", "max_permil = 0.5\nwarn_permil = 0.7", "checks[1].warn_permil"),
        ("max_permil = 0.5", 'max_permil = 0.5\nestimator = "x"', "checks[1].estimator: 'x'"),
        ("channel = 3\nwithin", "channel = 2\nwithin", "checks[2].channel: no scenario fault"),
        ('expect = "pass"', 'expect = "maybe"', "plan.expect: 'maybe' is not one of"),
        ('expect = "pass"', 'expect = "fail"', 'plan.expect: "fail", but no check'),
        ("within_samples = 10", "within_samples = 10\nexpect = 'fail'", 'plan.expect: "pass"'),
        ("duration_s = 10.0", "duration_s = -1.0", "bad.toml: scenario: duration_s: must be >"),
        ("gradient_permil = 20.0", "gradient_permill = 20", "scenario: track[1].gradient_permill"),
        (
            "[[checks]]\nname",
            "[config.fusion]\ntolerance = 1\n[[checks]]\nname",
            "config: fusion.tol",
        ),
        ("[plan]", "[plan\n", "bad.toml: not valid TOML"),
    ],
)
def test_broken_plan_names_file_and_key(old: str, new: str, message: str) -> None:
    assert old in GOOD
    with pytest.raises(ConfigError) as exc:
        parse_plan(GOOD.replace(old, new, 1), "bad.toml")
    text = str(exc.value)
    assert message in text
    assert "\n" not in text


def test_plan_level_rules() -> None:
    no_checks = GOOD[: GOOD.index("[[checks]]")]
    with pytest.raises(ConfigError, match="at least one"):
        parse_plan(no_checks, "x.toml")
    no_scenario = '[plan]\nexpect = "pass"\nduration_s = 5.0\n[[checks]]\n'
    no_scenario += 'kind = "gradient_error"\nmax_permil = 1.0\n'
    with pytest.raises(ConfigError, match=r"checks\[1\]\.kind: .*needs emulator truth"):
        parse_plan(no_scenario, "x.toml")
    nothing = '[plan]\nexpect = "pass"\n[[checks]]\nkind = "no_frame_loss"\n'
    with pytest.raises(ConfigError, match=r"x\.toml: plan: needs a"):
        parse_plan(nothing, "x.toml")
    steps_check = nothing.replace("[plan]", "[plan]\nduration_s = 1.0").replace(
        "no_frame_loss", 'step_gradient"\nmax_permil = 1.0\n#'
    )
    with pytest.raises(ConfigError, match="needs \\[\\[steps\\]\\]"):
        parse_plan(steps_check, "x.toml")
    dup = GOOD + '[[checks]]\nname = "steady"\nkind = "no_frame_loss"\n'
    with pytest.raises(ConfigError, match=r"checks\[3\]\.name: 'steady' is already"):
        parse_plan(dup, "x.toml")


def test_board_plan_with_steps() -> None:
    text = """
[plan]
expect = "pass"
[[steps]]
prompt = "level"
gradient_permil = 0.0
[[steps]]
prompt = "ten"
gradient_permil = 10.0
settle_s = 1.0
measure_s = 2.0
at_s = 30.0
[[checks]]
kind = "step_gradient"
max_permil = 0.3
"""
    plan = parse_plan(text, "board.toml")
    assert not plan.emulated
    assert [(s.settle_s, s.measure_s, s.at_s) for s in plan.steps] == [
        (2.0, 5.0, None),
        (1.0, 2.0, 30.0),
    ]
    with pytest.raises(ConfigError, match=r"steps\[2\]\.gradient_permil: missing"):
        parse_plan(text.replace("gradient_permil = 10.0", ""), "board.toml")


def test_steps_schedule_and_answers(tmp_path: Path) -> None:
    plan = load_plan("tilt-table")
    windows = schedule_steps(plan.steps, None)
    assert [(w.start_s, w.from_s, w.to_s) for w in windows] == [
        (0.0, 2.0, 8.0),
        (10.0, 12.0, 18.0),
        (20.0, 22.0, 28.0),
        (30.0, 32.0, 38.0),
    ]
    f = tmp_path / "answers.toml"
    f.write_text(
        '[[answers]]\n[[answers]]\nanswer = "skip"\n'
        '[[answers]]\nreference_permil = 30.2\nnote = "inclinometer"\n[[answers]]\n'
    )
    answers = load_answers(f)
    windows = schedule_steps(plan.steps, answers)
    assert windows[1].answer == "skip"
    assert windows[2].expected_permil == 30.2 and windows[2].note == "inclinometer"
    f.write_text('[[answers]]\nanswr = "ok"\n')
    with pytest.raises(ConfigError, match=r"answers.toml: answers\[1\]\.answr: unknown key"):
        load_answers(f)
    assert parse_answer("").answer == "ok"
    assert parse_answer(" s ").answer == "skip"
    assert parse_answer("q").answer == "abort"
    assert parse_answer("-10.3").reference_permil == -10.3


def test_shipped_plans_load_and_list() -> None:
    plans = shipped_plans()
    names = {p.stem for p in plans}
    for required in (
        "level",
        "ramp-up-30",
        "ramp-down-30",
        "accel-cruise-brake",
        "noisy-sensors",
        "link-can",
        "link-uart",
        "tilt-table",
    ):
        assert required in names
    # every fault kind that can hit one channel has its own plan
    for kind in ("stuck", "drift", "spike", "saturate", "status", "dropout", "crc"):
        assert f"fault-{kind}" in names
    for kind in ("loss", "duplicate", "reorder", "counter-jump"):
        assert f"fault-{kind}" in names
    expects = {load_plan(p).expect for p in plans}
    assert expects == {"pass", "fail"}  # some are meant to fail
    assert resolve_plan_path("level") == PLAN_DIR / "level.toml"
    with pytest.raises(ConfigError, match="no such plan"):
        resolve_plan_path("no-such-plan")


@pytest.mark.parametrize("path", shipped_plans(), ids=lambda p: p.stem)
def test_embedded_scenario_round_trips_through_toml(path: Path) -> None:
    plan = load_plan(path)
    assert plan.scenario is not None
    text = plan.scenario_toml()
    assert tomllib.loads(text) == plan.scenario_data
    again = scenario_from_dict(tomllib.loads(text), source=plan.scenario.source)
    assert again == plan.scenario


def test_dump_toml_nested() -> None:
    data = {
        "a": 1,
        "s": 'q"uote',
        "f": [1.5, 2.0],
        "t": {"x": True, "deep": {"y": -0.5}},
        "arr": [{"k": 1, "sub": {"z": "w"}}, {"k": 2}],
    }
    assert tomllib.loads(dump_toml(data)) == data


def test_warning_band_without_its_limit_uses_the_limit_default(tmp_path):
    """Regression: warn_count given, max_count left at its default, must not crash."""
    from bench.acceptance.plan import load_plan

    p = tmp_path / "p.toml"
    p.write_text(
        '[plan]\ntitle = "t"\nexpect = "pass"\n[scenario]\nduration_s = 1.0\n'
        '[[checks]]\nkind = "event_count"\nevents = ["CRC_ERROR"]\nwarn_count = 0\n'
    )
    plan = load_plan(p)
    assert plan.checks[0].params["warn_count"] == 0
