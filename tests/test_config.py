"""Calibration config: defaults are the ICD's nominal values; every bad key is named."""

from __future__ import annotations

import math

import pytest

from bench.cli import main
from bench.config import Config, load_config
from bench.errors import ConfigError


def test_defaults_are_the_icd_nominal_values():
    c = load_config(None)
    assert c.base_id == 0x100
    assert [ch.angle_deg for ch in c.channels] == [30.0, 0.0, -30.0]
    assert c.channels[0].scale == 2 * 9.80665 / 2**23
    assert c.channels[0].offset == 0.0
    assert c.g == 9.80665
    assert c.tolerance_permil == 1.0


def test_full_file_is_read(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text(
        "[board]\nbase_id = 0x200\n"
        "[[channels]]\nangle_deg = 30.2\n[[channels]]\nangle_deg = 0.1\nscale = 2.4e-6\n"
        "[[channels]]\nangle_deg = -29.8\noffset = 12.5\n"
        "[fusion]\ng = 9.81\ntolerance_permil = 0.5\n"
    )
    c = load_config(p)
    assert c.base_id == 0x200
    assert [ch.angle_deg for ch in c.channels] == [30.2, 0.1, -29.8]
    assert c.channels[1].scale == 2.4e-6 and c.channels[2].offset == 12.5
    assert c.g == 9.81 and c.tolerance_permil == 0.5
    assert math.isclose(c.angles_rad[0], math.radians(30.2))


def test_written_config_reads_back_equal(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text(Config().to_toml())
    c = load_config(p)
    assert (
        c.channels == Config().channels and c.g == Config().g and c.estimator == Config().estimator
    )


@pytest.mark.parametrize(
    ("text", "names"),
    [
        ("[fusion]\ntolerence_permil = 1\n", "fusion.tolerence_permil"),
        ("[fusion]\ng = -9.8\n", "fusion.g"),
        ("[fusion]\ng = 'fast'\n", "fusion.g"),
        ("[[channels]]\nangle_deg = 1\n", "channels"),
        (
            "[[channels]]\nangle_deg = 30\n[[channels]]\nangle_deg = 0\n[[channels]]\nangel = 3\n",
            "channels[3].angel",
        ),
        ("[[channels]]\nangle_deg = 95\n[[channels]]\n[[channels]]\n", "channels[1].angle_deg"),
        ("[board]\nbase_id = 0x180\n", "board.base_id"),
        ("[board]\nbase_id = 0x17E\n", "board.base_id"),
        ("[boards]\n", "boards"),
        ("[fusion\n", "not valid TOML"),
    ],
)
def test_bad_key_is_named_in_one_line(tmp_path, text, names):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_config(p)
    msg = str(err.value)
    assert names in msg and "bad.toml" in msg and "\n" not in msg


def test_cli_reports_bad_config_in_one_line_with_exit_2(tmp_path, capsys):
    p = tmp_path / "bad.toml"
    p.write_text("[fusion]\ntolerence_permil = 1\n")
    log = tmp_path / "x.log"
    log.write_text("")
    assert main(["replay", str(log), "--config", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("bench: error: bad.toml: fusion.tolerence_permil")


def test_missing_config_file_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config(tmp_path / "nope.toml")


def test_integer_too_large_for_a_float_is_a_one_line_error(tmp_path):
    p = tmp_path / "big.toml"
    p.write_text("[fusion]\ng = 1" + "0" * 400 + "\n")
    with pytest.raises(ConfigError, match=r"big.toml: fusion.g: must be finite"):
        load_config(p)
