"""Fuzzing the config, scenario and plan loaders: any input ends in a value or one ConfigError.

Two kinds of input:
* value swaps and line edits of real files (the calibration config, every shipped scenario
  and plan): structurally plausible TOML whose values are wrong in every way TOML allows
  (huge integers, nan/inf, dates, arrays, inline tables, empty strings);
* arbitrary nested dicts straight into the dict-level validators.

The property is the operator contract (docs/ARCHITECTURE.md): a bad file is one
``ConfigError`` line naming the file, never a TypeError/ValueError/OverflowError traceback.
"""

from __future__ import annotations

import datetime as dt
import math
import os
import re
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.acceptance.plan import Plan, parse_plan
from bench.config import Config, config_from_dict, load_config
from bench.errors import ConfigError
from devices.emulator import parse_scenario, scenario_from_dict
from devices.emulator.scenario import SCENARIO_DIR, Scenario

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = sorted(SCENARIO_DIR.glob("*.toml"))
PLANS = sorted((ROOT / "bench" / "plans").glob("*.toml"))
SCALE = float(os.environ.get("BENCH_FUZZ_SCALE", "1"))
"""BENCH_FUZZ_SCALE=20 runs twenty times the examples (a longer hunt than the default run)."""


def _settings(n: int) -> settings:
    return settings(
        max_examples=max(1, int(n * SCALE)),
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    )


FUZZ = _settings(60)

# --------------------------------------------------------------------------- TOML values
TOML_LITERALS = st.one_of(
    st.integers(min_value=-(2**63), max_value=2**63 - 1).map(str),
    st.sampled_from(
        [
            "0",
            "-1",
            "1e308",
            "-1e308",
            "5e-324",
            "nan",
            "inf",
            "-inf",
            "+nan",
            "0x7FF",
            "0o777",
            "0b101",
            "1979-05-27",
            "1979-05-27T07:32:00Z",
            "07:32:00",
            "true",
            "false",
            '""',
            '"x"',
            "'\\u0000'",
            '"\\u00e9\\u00e9"',
            "[]",
            "[1, 2, 3]",
            '[1, "a"]',
            "[[1], [2]]",
            "{}",
            "{ a = 1 }",
            "9223372036854775807",
            "-9223372036854775808",
            "1_000_000",
            "3.0",
            "-0.0",
            "1e-9",
            "[nan]",
            '"' + "x" * 300 + '"',
            '["SELFTEST", "BOGUS"]',
            '"uart"',
            '"bus"',
            "4",
            "1000",
            "1001",
            "49",
            "0.95",
        ]
    ),
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=20).map(
        lambda s: '"' + s.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    ),
)
_KEY_LINE = re.compile(r"^(\s*[A-Za-z0-9_.\"-]+\s*=\s*)(.+?)(\s*#.*)?$")


@st.composite
def edited(draw: st.DrawFn, text: str) -> str:
    """``text`` with 1-3 edits: a value swapped, a line dropped or duplicated, a key added."""
    lines = text.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        if not lines:
            break
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["swap", "swap", "swap", "drop", "dup", "key", "header"]))
        m = _KEY_LINE.match(lines[i])
        if op == "swap" and m:
            lines[i] = m.group(1) + draw(TOML_LITERALS)
        elif op == "drop":
            del lines[i]
        elif op == "dup":
            lines.insert(i, lines[i])
        elif op == "key":
            key = draw(st.sampled_from(["bogus", "duration_s", "kind", "channel", "seed", "x y"]))
            lines.insert(i + 1, f"{key} = {draw(TOML_LITERALS)}")
        elif op == "header":
            lines.insert(i, draw(st.sampled_from(["[board]", "[[faults]]", "[[checks]]", "[x]"])))
    return "\n".join(lines) + "\n"


def _only_config_errors(fn: Any, *args: Any) -> Any:
    """``fn(*args)``, or None for a ConfigError: one line, naming the file (``args[1]`` or
    the path ``args[0]``)."""
    try:
        return fn(*args)
    except ConfigError as exc:
        text = str(exc)
        assert text and "\n" not in text.strip(), f"not one line: {text!r}"
        assert "Traceback" not in text
        name = args[1] if len(args) > 1 else Path(args[0]).name
        assert str(name) in text, f"the file is not named: {text!r}"
        return None


def _loaded(kind: type, fn: Any, *args: Any, refused: bool) -> Any:
    """What ``fn`` made of the input: a ``kind``, or None for one ConfigError line; None
    when the input is ``refused`` (invalid TOML, an unknown key) by what the test knows."""
    got = _only_config_errors(fn, *args)
    assert got is None or isinstance(got, kind), f"{type(got).__name__}, not {kind.__name__}"
    assert not (refused and got is not None), f"accepted what must be refused: {args[0]!r}"
    return got


STRANGERS = {"bogus", "", "x", "x y"}  # keys no loader knows (edited() and _tree() add them)


def _toml(text: str) -> dict[str, Any] | None:
    """The text's TOML as the standard library reads it (after an editor's byte-order mark,
    which the loaders skip), None when it is not TOML."""
    try:
        return tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError:
        return None


def _has_stranger(tree: Any) -> bool:
    """A key no loader knows, anywhere in a loader's tables (not inside values)."""
    if isinstance(tree, list):
        return any(_has_stranger(t) for t in tree)
    if not isinstance(tree, dict):
        return False
    return bool(STRANGERS & tree.keys()) or any(_has_stranger(v) for v in tree.values())


def _refused_text(text: str) -> bool:
    """Text every loader must refuse: not TOML, or a table with a key none knows."""
    tree = _toml(text)
    return tree is None or _has_stranger(tree)


def _usable_config(cfg: Config) -> None:
    assert all(math.isfinite(c.angle_deg) and c.scale > 0 for c in cfg.channels)
    assert len({c.angle_deg for c in cfg.channels}) == 3


def _usable_scenario(sc: Scenario) -> None:
    assert math.isfinite(sc.duration_s) and sc.duration_s > 0, sc.duration_s
    assert sc.sample_rate_hz > 0, sc.sample_rate_hz


# --------------------------------------------------------------------------- config
@FUZZ
@given(st.data())
def test_edited_config_is_a_config_or_one_config_error(tmp_path_factory: Any, data: Any) -> None:
    base = Config().to_toml()
    text = data.draw(edited(base))
    path = tmp_path_factory.mktemp("cfg") / "cal.toml"
    path.write_text(text, encoding="utf-8")
    cfg = _loaded(Config, load_config, path, refused=_refused_text(text))
    if cfg is not None:  # what loads must be usable, and written back it reads the same
        _usable_config(cfg)
        again = tmp_path_factory.mktemp("again") / "again.toml"
        again.write_text(cfg.to_toml(), encoding="utf-8")
        assert replace(load_config(again), source=cfg.source, path=cfg.path) == cfg


NASTY_SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(),
    st.text(max_size=8),
    st.just(dt.date(1979, 5, 27)),
    st.just(dt.datetime(1979, 5, 27, 7, 32)),
    st.just(dt.time(7, 32)),
)
NASTY_VALUES = st.recursive(
    NASTY_SCALARS,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)


def _tree(keys: list[str]) -> st.SearchStrategy[dict[str, Any]]:
    """Dicts using the loader's real keys (and a few strangers), with nasty values."""
    key = st.sampled_from([*keys, "bogus", ""])
    return st.dictionaries(key, NASTY_VALUES, max_size=6)


CONFIG_TREE = st.fixed_dictionaries(
    {},
    optional={
        "board": _tree(["base_id", "sample_rate_hz"]),
        "channels": st.lists(_tree(["angle_deg", "scale", "offset"]), max_size=4),
        "fusion": _tree(["g", "tolerance_permil"]),
        "estimator": _tree(["residual_limit_mps2", "stuck_window_s", "recover_s", "coast_s"]),
        "bogus": NASTY_VALUES,
    },
)


@FUZZ
@given(CONFIG_TREE)
def test_config_dict_is_a_config_or_one_config_error(data: dict[str, Any]) -> None:
    cfg = _loaded(Config, config_from_dict, data, "fuzz.toml", refused=_has_stranger(data))
    if cfg is not None:
        _usable_config(cfg)


# --------------------------------------------------------------------------- scenario
SCENARIO_TREE = st.fixed_dictionaries(
    {},
    optional={
        "duration_s": NASTY_VALUES,
        "sample_rate_hz": NASTY_VALUES,
        "seed": NASTY_VALUES,
        "base_id": NASTY_VALUES,
        "track": st.lists(_tree(["length_m", "gradient_permil", "vertical_curve_m"]), max_size=3),
        "train": st.lists(_tree(["duration_s", "accel_mps2", "allow_reverse"]), max_size=3),
        "channels": st.lists(_tree(["angle_deg", "noise_mps2", "vibration_hz"]), max_size=4),
        "board": _tree(["frame_gap_us", "latency_us", "temperature_c"]),
        "odometer": _tree(["drift_ppm", "offset_s", "lag_s"]),
        "faults": st.lists(
            _tree(["kind", "channel", "start_s", "end_s", "probability", "bits", "jump", "code"]),
            max_size=3,
        ),
    },
)


@FUZZ
@given(SCENARIO_TREE)
def test_scenario_dict_is_a_scenario_or_one_config_error(data: dict[str, Any]) -> None:
    sc = _loaded(Scenario, scenario_from_dict, data, "fuzz.toml", refused=_has_stranger(data))
    if sc is not None:
        _usable_scenario(sc)


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
@_settings(25)
@given(data=st.data())
def test_edited_scenario_is_a_scenario_or_one_config_error(path: Path, data: Any) -> None:
    text = data.draw(edited(path.read_text(encoding="utf-8")))
    sc = _loaded(Scenario, parse_scenario, text, path.name, refused=_refused_text(text))
    if sc is not None:
        _usable_scenario(sc)


# --------------------------------------------------------------------------- plans
@pytest.mark.parametrize("path", PLANS[:6], ids=lambda p: p.name)
@_settings(20)
@given(data=st.data())
def test_edited_plan_is_a_plan_or_one_config_error(path: Path, data: Any) -> None:
    text = data.draw(edited(path.read_text(encoding="utf-8")))
    _loaded(Plan, parse_plan, text, path.name, path, refused=_refused_text(text))


@FUZZ
@given(st.binary(max_size=200))
def test_plan_config_scenario_from_binary_garbage(blob: bytes) -> None:
    text = blob.decode("utf-8", "replace")
    tree = _toml(text)
    _loaded(Plan, parse_plan, text, "garbage.toml", refused=tree is None or "plan" not in tree)
    sc = _loaded(Scenario, parse_scenario, text, "garbage.toml", refused=_refused_text(text))
    if sc is not None:
        _usable_scenario(sc)


def _loader(name: str) -> Any:
    if name == "config":
        return load_config
    if name == "scenario":
        from devices.emulator import load_scenario

        return load_scenario
    from bench.acceptance.plan import load_plan

    return load_plan


@pytest.mark.parametrize("kind", ["binary", "utf16", "folder"])
@pytest.mark.parametrize("loader", ["config", "scenario", "plan"])
def test_binary_and_folder_files_are_one_config_error(
    tmp_path: Path, loader: str, kind: str
) -> None:
    p = tmp_path / "x.toml"
    if kind == "binary":
        p.write_bytes(b"\xff\xfe\x00garbage\x00" * 10)
    elif kind == "utf16":
        p.write_bytes("[board]\nbase_id = 256\n".encode("utf-16"))
    else:
        p.mkdir()
    with pytest.raises(ConfigError) as err:
        _loader(loader)(p)
    assert str(p.name) in str(err.value) and "\n" not in str(err.value)
