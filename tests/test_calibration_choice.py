"""Which calibration a command uses, said and stored (issue 18): an emulated board as built,
a recorded MCAP's own, a --config file, else nominal; a scenario or plan is not a config."""

from __future__ import annotations

import csv
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.config import Config, load_config
from bench.mcaplog.recorded import read_metadata, recorded_config
from tests.helpers import until

REPO = Path(__file__).resolve().parents[1]
LEVEL_RUN = REPO / "devices" / "scenarios" / "level_run.toml"
NOMINAL_SCALE = 2 * 9.80665 / 2**23  # ICD: 24-bit codes, +-2 g full scale


def short_level_run(tmp_path: Path, seconds: float = 3.0) -> Path:
    """level_run.toml (as-built angles 30.2/0.1/-29.8, no faults), cut short."""
    text = LEVEL_RUN.read_text()
    assert "duration_s = 120.0" in text
    path = tmp_path / "level3.toml"
    path.write_text(text.replace("duration_s = 120.0", f"duration_s = {seconds}"))
    return path


def read_csv(path: Path) -> dict[str, np.ndarray]:
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    numeric = [k for k in rows[0] if k != "utc"]  # utc is a timestamp
    return {k: np.array([float(r[k]) if r[k] else math.nan for r in rows]) for k in numeric}


def test_example_calibration_sheet_loads_with_its_documented_values() -> None:
    sheet = REPO / "examples" / "calibration.toml"
    config = load_config(sheet)
    assert [c.angle_deg for c in config.channels] == [30.04, -0.02, -29.97]
    assert all(c.scale == NOMINAL_SCALE and c.offset == 0.0 for c in config.channels)
    assert (config.base_id, config.sample_rate_hz, config.g) == (0x100, 200, 9.80665)
    assert config.origin == "file" and config.describe() == f"file {sheet}"
    # a documented sheet: every key is explained (a comment on its line) at least once
    keys: dict[str, bool] = {}
    for line in sheet.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith("#"):
            key = line.split("=")[0].strip()
            keys[key] = keys.get(key, False) or "#" in line
    assert len(keys) == 17 and all(keys.values()), keys


@pytest.mark.parametrize(
    ("relative", "what"),
    [("devices/scenarios/level_run.toml", "emulator scenario"), ("bench/plans/level.toml", "plan")],
)
def test_a_scenario_or_plan_given_as_config_is_one_clear_line(
    relative: str, what: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["replay", "x.log", "--config", str(REPO / relative)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("bench: error:")
    assert what in err and "not a calibration config" in err and "unknown key" not in err


def test_emulate_writes_the_board_sheet_beside_a_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sc = short_level_run(tmp_path, 1.0)
    log, cal = tmp_path / "run.log", tmp_path / "cal.toml"
    assert main(["emulate", str(sc), "--out", str(log), "--calibration-out", str(cal)]) == 0
    assert f"bench replay {log} --config {cal}" in capsys.readouterr().out
    built = tomllib.loads(sc.read_text())
    config = load_config(cal)
    assert [c.angle_deg for c in config.channels] == [c["angle_deg"] for c in built["channels"]]
    assert config.sample_rate_hz == built["sample_rate_hz"] == 500


def test_emulator_log_with_its_sheet_replays_like_its_mcap_with_the_recorded_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sc = short_level_run(tmp_path, 2.0)
    log, cal, mcap = tmp_path / "run.log", tmp_path / "cal.toml", tmp_path / "run.mcap"
    assert main(["emulate", str(sc), "--out", str(log), "--calibration-out", str(cal)]) == 0
    assert main(["emulate", str(sc), "--out", str(mcap)]) == 0
    assert "calibration recorded in the log: scenario level3.toml as built" in (
        capsys.readouterr().out
    )
    recorded = recorded_config(mcap)
    assert recorded is not None and recorded.origin == "scenario"
    assert read_metadata(mcap)["run"]["calibration"] == "scenario level3.toml as built"
    assert recorded.describe() == "recorded in run.mcap (scenario level3.toml as built)"
    a, b = tmp_path / "mcap.csv", tmp_path / "log.csv"
    assert main(["replay", str(mcap), "--csv", str(a)]) == 0
    err = capsys.readouterr().err
    assert "calibration: recorded in run.mcap (scenario level3.toml as built)" in err
    assert main(["replay", str(log), "--config", str(cal), "--csv", str(b)]) == 0
    assert f"calibration: file {cal} (ch1 30.2 deg, ch2 0.1 deg, ch3 -29.8 deg" in (
        capsys.readouterr().err
    )
    assert a.read_text() == b.read_text()
    # level track: the estimator with the board's own angles reads ~0 (within its sigma limit
    # of 0.35 permil, 2 s after pulling away); nominal angles would read about +6.5 permil
    assert abs(np.nanmean(read_csv(a)["gradient_signed_permil"])) < 0.2


def test_a_log_without_calibration_says_it_replays_with_nominal_values(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    sc = short_level_run(tmp_path, 0.5)
    log = tmp_path / "run.log"
    assert main(["emulate", str(sc), "--out", str(log), "-q"]) == 0
    assert main(["replay", str(log), "-q"]) == 0
    assert capsys.readouterr().err == ""  # -q: nothing
    assert main(["replay", str(log)]) == 0
    err = capsys.readouterr().err
    assert "bench: calibration: nominal ICD values (ch1 30 deg, ch2 0 deg, ch3 -30 deg" in err
    assert "--calibration-out" in err


def test_run_emulate_level_run_is_calibrated_as_built_and_replays_identically(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """bench run --emulate level_run ("no faults") used nominal angles: v1 and v2 failed on
    every sample and the estimator read +2.8 permil on level track."""
    sc = short_level_run(tmp_path, 3.0)
    live, again, nominal = (tmp_path / f"{n}.csv" for n in ("live", "again", "nominal"))
    mcap = tmp_path / "run.mcap"
    assert main(["run", "--emulate", str(sc), "--csv", str(live), "--mcap", str(mcap)]) == 0
    err = capsys.readouterr().err
    assert "bench: calibration: scenario level3.toml as built (ch1 30.2 deg, ch2 0.1 deg" in err
    meta = read_metadata(mcap)
    assert meta["run"]["calibration"] == "scenario level3.toml as built"
    assert meta["config"]["origin"] == "scenario"
    rows = read_csv(live)
    assert len(rows["v1"]) > 1000
    for k in ("v1", "v2"):
        assert np.mean(rows[k] == 0) < 0.95, k  # not failing on every sample
    # level track: what it gives is 0 within its own sigma (0.1-0.3 permil over the first
    # seconds, as the filter settles from a cold start), and most samples are given (with the
    # nominal angles it withholds nine in ten, below)
    grad, sigma = rows["gradient_signed_permil"], rows["gradient_sigma_permil"]
    given = np.isfinite(grad)
    assert given.mean() > 0.5 and abs(np.nanmean(grad)) < 0.15
    assert np.mean(np.abs(grad[given]) <= 2.0 * sigma[given]) > 0.95
    # the replay of its log takes the recorded calibration: the same rows, bit for bit
    assert main(["replay", str(mcap), "--csv", str(again), "-q"]) == 0
    assert again.read_text() == live.read_text()
    # and the nominal angles reproduce the observation, so the checks above can fail
    empty = tmp_path / "nominal.toml"
    empty.write_text("")
    assert main(["replay", str(mcap), "--config", str(empty), "--csv", str(nominal), "-q"]) == 0
    bad = read_csv(nominal)
    assert np.all(bad["v1"] == 0) and np.all(bad["v2"] == 0)
    # the estimator: wrong angles leave a parity residual no channel explains, which its sigma
    # takes in, so it withholds (it read +2.8 permil as if sure before it did)
    assert np.isnan(bad["gradient_signed_permil"]).mean() > 0.9


def test_tui_replay_of_an_mcap_uses_the_recorded_calibration(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    sc = short_level_run(tmp_path, 0.5)
    mcap = tmp_path / "emu.mcap"
    assert main(["emulate", str(sc), "--out", str(mcap), "-q"]) == 0
    used: list[Config] = []
    import bench.commands.tui as tui_command
    import bench.live.session as session_module

    monkeypatch.setattr(session_module, "live_session", lambda setup, config, *a, **k: setup)
    monkeypatch.setattr(tui_command, "show", lambda setup, **app: used.append(setup) or 0)
    real_setup = session_module.replay_setup

    def setup_spy(path: str, config: Config, **kwargs: object) -> object:
        used.append(config)
        return real_setup(path, config, **kwargs)

    monkeypatch.setattr(session_module, "replay_setup", setup_spy)
    assert main(["tui", "--replay", str(mcap)]) == 0
    used[1].close()
    config = used[0]
    assert [c.angle_deg for c in config.channels] == [30.2, 0.1, -29.8]
    assert config.sample_rate_hz == 500
    assert "calibration: recorded in emu.mcap (scenario level3.toml as built)" in (
        capsys.readouterr().err
    )


def test_tui_and_demo_on_an_emulated_board_use_it_as_built(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import bench.commands.tui as tui_command
    import bench.engine.client as engine

    sc = short_level_run(tmp_path, 0.5)
    plans: list[object] = []
    monkeypatch.setattr(engine, "start_engine", lambda plan, warn: plans.append(plan))
    monkeypatch.setattr(tui_command, "show", lambda session, **app: 0)
    assert main(["tui", "--emulate", str(sc)]) == 0
    assert main(["demo", "--scenario", str(sc)]) == 0
    cal = tmp_path / "cal.toml"
    cal.write_text("[[channels]]\nangle_deg = 31\n[[channels]]\n[[channels]]\n")
    assert main(["tui", "--emulate", str(sc), "--config", str(cal)]) == 0
    angles = [[c.angle_deg for c in p.config.channels] for p in plans]  # type: ignore[attr-defined]
    assert angles == [[30.2, 0.1, -29.8], [30.2, 0.1, -29.8], [31.0, 0.0, -30.0]]
    err = capsys.readouterr().err
    assert err.count("calibration: scenario level3.toml as built") == 2
    assert f"calibration: file {cal}" in err


def test_live_bus_without_config_is_nominal_and_says_so() -> None:
    from bench.config_choice import live_config

    config = live_config(None, None)
    assert config == Config() and config.origin == "nominal"
    assert config.announcement() == (
        "calibration: nominal ICD values (ch1 30 deg, ch2 0 deg, ch3 -30 deg; tolerance 1 permil)"
    )


def test_accept_says_and_records_its_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    out = tmp_path / "level"
    assert main(["accept", "level", "--out", str(out), "--no-plots"]) == 0
    err = " ".join(capsys.readouterr().err.split())
    assert "bench: calibration: scenario of plan level as built (ch1 30 deg" in err
    record = json.loads((out / "record.json").read_text())
    assert record["config"]["origin"] == "scenario"
    assert record["config"]["described"] == "scenario of plan level as built"
    meta = read_metadata(out / "run.mcap")
    assert meta["config"]["origin"] == "scenario"
    assert meta["run"]["calibration"] == "scenario of plan level as built"


def test_accept_on_an_emulated_board_uses_that_board_as_built(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    sc = short_level_run(tmp_path, 1.0)
    plan = tmp_path / "board.toml"
    plan.write_text(
        '[plan]\nexpect = "pass"\nduration_s = 0.5\n'
        '[config.fusion]\ntolerance_permil = 2.0\n[[checks]]\nkind = "no_frame_loss"\n'
    )
    out = tmp_path / "out"
    assert main(["accept", str(plan), "--emulate", str(sc), "--out", str(out), "--no-plots"]) == 0
    record = json.loads((out / "record.json").read_text())
    values = record["config"]["values"]
    assert [c["angle_deg"] for c in values["channels"]] == [30.2, 0.1, -29.8]
    assert values["tolerance_permil"] == 2.0  # the plan's overlay on top
    assert record["config"]["described"] == (
        f"scenario level3.toml as built + [config] of {plan.name}"
    )


def test_demo_log_replays_to_the_results_shown_live(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Replaying `bench demo`'s log gave other results than the screen had shown (nominal
    angles instead of the board's): the recorded calibration makes them identical."""

    import bench.commands.tui as tui_command

    def headless(session: object, **app_kwargs: object) -> int:
        session.start()  # type: ignore[attr-defined]
        done = session.snapshot  # type: ignore[attr-defined]
        until(lambda: done(last=1).extra.get("emulator_done"), "the emulator to finish")
        session.stop()  # type: ignore[attr-defined]
        return 0

    monkeypatch.setattr(tui_command, "show", headless)
    sc = short_level_run(tmp_path, 2.0)
    mcap = tmp_path / "demo.mcap"
    assert main(["demo", "--scenario", str(sc), "--speed", "4", "--mcap", str(mcap)]) == 0
    capsys.readouterr()
    assert read_metadata(mcap)["config"]["origin"] == "scenario"
    assert main(["replay", str(mcap), "--compare", "-q"]) == 0  # identical to the live rows
    assert "compare: identical" in capsys.readouterr().out
    empty = tmp_path / "nominal.toml"
    empty.write_text("")
    assert main(["replay", str(mcap), "--compare", "-q", "--config", str(empty)]) == 1
