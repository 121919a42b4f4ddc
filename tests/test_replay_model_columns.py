"""`bench replay --smooth`'s estimate columns (issue 26): the wheel-diameter error, each
channel's bias, the body's pitch, each with its sigma, per sample.

Expectations are the emulator's configured truth, not the smoother's: a 2 % wheel, and
biases on the three channels that the calibration sheet given to the replay does not
know (its offsets zeroed). The biases point along the parity vector p = cos(theta) x
sin(theta) of the mounting angles (30, 0, -30 deg): the one direction of the three
readings that neither the gradient, nor the acceleration, nor gravity can take, so the
whole bias must show in the bias columns (a bias along cos(theta) would be the gradient's:
see test_accept_smoothed) and the gradient must stay the track's.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bench.cli import main
from tests.test_replay_smooth import (
    GRADIENT,
    SCENARIO,
    WHEEL,
    channels_toml,
    emulate_run,
    uncalibrated,
)

ANGLES = (30.0, 0.0, -30.0)
BETA = 2e-3  # m/s^2, the bias's length along the unit parity vector
_c = np.cos(np.radians(ANGLES))
_s = np.sin(np.radians(ANGLES))
PARITY = np.cross(_c, _s) / np.linalg.norm(np.cross(_c, _s))  # (-0.447, 0.775, -0.447)
BIAS = BETA * PARITY


@pytest.fixture(scope="module")
def board(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = emulate_run(
        tmp_path_factory.mktemp("estimates"), SCENARIO + channels_toml(ANGLES, list(BIAS))
    )
    uncalibrated(d)  # the sheet as built less its offsets: the replay does not know the biases
    return d


def _replay(d: Path) -> list[str]:
    return ["replay", str(d / "run.log"), "--config", str(d / "cal0.toml"), "--smooth"]


@pytest.fixture(scope="module")
def table(board: Path) -> pa.Table:
    assert main([*_replay(board), "-q", "--parquet", str(board / "run.parquet")]) == 0
    return pq.read_table(board / "run.parquet")


def test_the_replay_says_each_bias_it_found(
    board: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(_replay(board)) == 0
    line = next(x for x in capsys.readouterr().err.splitlines() if "ch1 bias" in x)
    for i, truth in enumerate(BIAS, 1):
        got = re.search(rf"ch{i} bias ([-+.\d]+) mm/s\^2 \(1-sigma ([.\d]+)\)", line)
        assert got is not None, line
        value, sigma = float(got[1]), float(got[2])
        assert abs(value - 1e3 * truth) <= 2.0 * sigma, line
    assert "body pitch" in line and "moving" not in line  # nothing drifts in this run


def _col(table: pa.Table, name: str) -> np.ndarray:
    return np.asarray(table[name].to_numpy(zero_copy_only=False), dtype=np.float64)


def test_the_wheel_diameter_error_is_in_every_row_within_its_two_sigma(table: pa.Table) -> None:
    e = _col(table, "wheel_diameter_error_smoothed")
    sig = _col(table, "wheel_diameter_error_smoothed_sigma")
    assert len(e) == table.num_rows and np.isfinite(e).all()
    assert np.all(np.abs(e - WHEEL) <= 2.0 * sig)
    # 0.6 %: the acceleration phases tell (1 + g C) / (1 + E), and the body's compliance C
    # only the normal axis (docs/ESTIMATOR.md)
    assert np.all((sig > 0.0) & (sig < 0.006))


def test_each_channel_s_bias_is_found_within_its_two_sigma(table: pa.Table) -> None:
    for i, truth in enumerate(BIAS, 1):
        b = _col(table, f"bias{i}_smoothed_mps2")
        sig = _col(table, f"bias{i}_smoothed_sigma_mps2")
        assert np.all(np.abs(b - truth) <= 2.0 * sig), (i, b[0], truth, sig[0])
        assert np.all(sig < abs(truth))  # told from zero: the sigma is below the bias


def test_the_parity_part_of_the_biases_is_the_injected_one(table: pa.Table) -> None:
    """p . b is seen in every reading whatever the motion: nearly all of BETA, less the pull
    of the bias prior (0.5 mm/s^2, config bias_sigma_mps2) against about 7000 samples of
    0.01 m/s^2 noise, a few per cent (hand: 1 / (1 + 0.01^2 / 7000 / 0.0005^2) = 0.95)."""
    b = np.column_stack([_col(table, f"bias{i}_smoothed_mps2") for i in (1, 2, 3)])
    seen = b @ PARITY
    assert np.all(np.abs(seen - BETA) < 0.1 * BETA), (seen.min(), seen.max())


def test_the_body_pitch_is_level_and_the_gradient_the_track_s(table: pa.Table) -> None:
    pitch = _col(table, "body_pitch_smoothed_rad")
    sig = _col(table, "body_pitch_smoothed_sigma_rad")
    assert np.all(np.abs(pitch) <= 2.0 * sig)  # [body_pitch] is off: the body stays level
    g = _col(table, "gradient_smoothed_permil")
    given = np.isfinite(g)
    assert given.mean() > 0.85
    assert math.sqrt(float(np.mean((g[given] - GRADIENT) ** 2))) < 0.1


def test_a_state_the_model_gains_becomes_two_columns_by_its_name(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Issue 26's body-pitch compliance (or any other new state) needs no edit here."""
    from bench.fusion.model import state
    from bench.records.columns import columns_of
    from bench.replay import model_columns

    monkeypatch.setattr(state, "NAMES", (*state.NAMES, "compliance_x"))
    table, dtype = model_columns.fields_and_dtype()
    names = [c.name for c in columns_of(dtype, table)]
    assert names[-2:] == ["model_compliance_x_smoothed", "model_compliance_x_smoothed_sigma"]
    assert "body_pitch_smoothed_rad" in names and "v" not in names
