"""Hostile operator input (issue 16 items 6, 8, 13): configs, scenarios, plans and logs that
passed validation or gave a traceback. Each case builds its file here and runs the real
command; the contract is a one-line ``bench: error: ...`` (exit 2) that says what is wrong
and what is allowed, or a clean run.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from tests.test_fuzz_nasty_logs import time_limit

BOARD = """[board]
sample_rate_hz = 200
"""


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    code = main(list(argv))
    return code, capsys.readouterr().err


def one_error(code: int, err: str) -> str:
    """The single `bench: error:` line (asserting there is exactly one, and exit 2)."""
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("bench: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def small_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from devices.emulator import scenario_from_dict, simulate
    from devices.writers import write_candump

    path = tmp_path_factory.mktemp("hostile") / "small.log"
    frames = simulate(scenario_from_dict({"duration_s": 0.5, "seed": 3})).frames
    write_candump(path, frames)
    return path


# --------------------------------------------------------------------- item 8: deep nesting
DEEP = "x = " + "[" * 5000 + "]" * 5000 + "\n"


@pytest.mark.parametrize("what", ["config", "scenario", "plan"])
def test_deeply_nested_toml_is_one_line(tmp_path, capsys, small_log, what):
    path = tmp_path / f"deep_{what}.toml"
    path.write_text(DEEP)
    argv = {
        "config": ["replay", str(small_log), "--config", str(path), "-q"],
        "scenario": ["emulate", str(path), "--out", str(tmp_path / "o.log"), "-q"],
        "plan": ["accept", str(path), "--out", str(tmp_path / "acc")],
    }[what]
    line = one_error(*run_cli(capsys, *argv))
    assert path.name in line and "nest" in line


# ------------------------------------------------------------------- item 13: minor ones
def test_utf8_bom_config_is_read(tmp_path, capsys, small_log):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + BOARD.encode())
    code, err = run_cli(capsys, "replay", str(small_log), "--config", str(path), "-q")
    assert code == 0, err


@pytest.mark.parametrize("angles", [(1e-7, 1e-7 + 1e-7, -30.0), (30.0, 30.0 + 1e-7, -30.0)])
def test_near_singular_geometry_is_refused(tmp_path, capsys, small_log, angles):
    path = tmp_path / "singular.toml"
    path.write_text(BOARD + "".join(f"[[channels]]\nangle_deg = {a!r}\n" for a in angles))
    line = one_error(*run_cli(capsys, "replay", str(small_log), "--config", str(path), "-q"))
    assert "singular.toml" in line and "apart" in line


def test_control_character_in_plan_title_is_refused(tmp_path, capsys):
    plan = tmp_path / "ctl.toml"
    plan.write_text(
        '[plan]\ntitle = "bell \\u0007 here"\nexpect = "pass"\n'
        '[scenario]\nduration_s = 1.0\n[[checks]]\nkind = "no_frame_loss"\n'
    )
    line = one_error(*run_cli(capsys, "accept", str(plan), "--out", str(tmp_path / "acc")))
    assert "plan.title" in line and "U+0007" in line


def test_junit_stays_well_formed_with_odd_but_legal_text(tmp_path, capsys):
    """Tabs, markup and non-ASCII in names pass and junit.xml parses."""
    plan = tmp_path / "odd.toml"
    plan.write_text(
        '[plan]\ntitle = "tab\\there <b>&amp;</b> ‰ ü"\nexpect = "pass"\n'
        "[scenario]\nduration_s = 1.0\n"
        '[[checks]]\nname = "]]> <x/> \\"q\\""\nkind = "no_frame_loss"\n'
    )
    out = tmp_path / "acc"
    code, err = run_cli(capsys, "accept", str(plan), "--out", str(out), "--no-plots")
    assert code == 0, err
    ET.parse(out / "junit.xml")


def test_empty_blf_says_empty(tmp_path, capsys):
    path = tmp_path / "empty.blf"
    path.write_bytes(b"")
    line = one_error(*run_cli(capsys, "replay", str(path), "-q"))
    assert "empty.blf" in line and "empty" in line.replace("empty.blf", "")
    assert "unpack" not in line


def test_short_blf_says_not_blf(tmp_path, capsys):
    path = tmp_path / "short.blf"
    path.write_bytes(b"LOGG" + bytes(20))
    line = one_error(*run_cli(capsys, "replay", str(path), "-q"))
    assert "short.blf" in line and "unpack" not in line


def test_replaying_a_results_csv_is_refused(tmp_path, capsys, small_log):
    results = tmp_path / "results.csv"
    assert run_cli(capsys, "replay", str(small_log), "--csv", str(results), "-q")[0] == 0
    line = one_error(*run_cli(capsys, "replay", str(results), "-q"))
    assert "results.csv" in line and "not a" in line and "unpack" not in line


def test_can_csv_log_still_replays(tmp_path, capsys, small_log):
    import can

    from devices.bus import messages_from_frames
    from devices.formats import open_log

    frames = np.concatenate([b.frames for b in open_log(small_log).batches()])
    path = tmp_path / "can.csv"
    with can.CSVWriter(path) as w:
        for m in messages_from_frames(frames):
            w.on_message_received(m)
    code, err = run_cli(capsys, "replay", str(path), "-q")
    assert code == 0, err


@pytest.mark.parametrize("value", ["-5", "0", "nan", "inf", "1e300"])
def test_run_duration_must_be_positive_and_finite(capsys, value):
    """A usage error like every other bad option: argparse's usage and one error line."""
    with pytest.raises(SystemExit) as exc:
        main(["run", "--emulate", "demo", "--duration", value, "--no-log"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "Traceback" not in err
    assert "argument --duration: must be in (0, " in err.splitlines()[-1]


# ------------------------------------------------------------- item 6: bounded numbers
BIG = ["1000000000", "1e6", "1e300", str(2**63 - 1), str(-(2**63))]


@pytest.mark.parametrize("value", BIG)
@pytest.mark.parametrize(
    "key",
    [
        "board.sample_rate_hz",
        "board.base_id",
        "fusion.g",
        "fusion.tolerance_permil",
        "channels.scale",
        "channels.offset",
        "channels.angle_deg",
        "estimator.residual_window_s",
        "estimator.stuck_window_s",
        "estimator.recover_s",
        "estimator.standstill_s",
        "estimator.coast_s",
        "estimator.residual_limit_mps2",
        "estimator.speed_noise_mps",
        "estimator.jerk_psd",
        "estimator.a_ref_sigma_mps2",
        "estimator.clock_drift_ppm",
    ],
)
def test_huge_config_numbers_are_bounded(tmp_path, capsys, small_log, key, value):
    table, name = key.split(".")
    if table == "channels":
        text = "".join(
            f"[[channels]]\nangle_deg = {a}\n" + (f"{name} = {value}\n" if k == 0 else "")
            for k, a in enumerate((30.0, 0.0, -30.0))
        )
        if name == "angle_deg":
            text = text.replace("angle_deg = 30.0\nangle_deg", "angle_deg")
    else:
        text = f"[{table}]\n{name} = {value}\n"
    path = tmp_path / "big.toml"
    path.write_text(text)
    code, err = run_cli(capsys, "replay", str(small_log), "--config", str(path), "-q")
    assert "Traceback" not in err
    if code != 0:
        line = one_error(code, err)
        assert name in line and ("must be" in line or "expected" in line or "lie in" in line)


def test_config_rate_bound_names_the_icd(tmp_path, capsys, small_log):
    path = tmp_path / "rate.toml"
    path.write_text("[board]\nsample_rate_hz = 1000000000\n")
    line = one_error(*run_cli(capsys, "replay", str(small_log), "--config", str(path), "-q"))
    assert "sample_rate_hz" in line and "1000" in line and "50" in line


def test_residual_window_bound_is_in_the_message(tmp_path, capsys, small_log):
    path = tmp_path / "win.toml"
    path.write_text("[estimator]\nresidual_window_s = 1e6\n")
    line = one_error(*run_cli(capsys, "replay", str(small_log), "--config", str(path), "-q"))
    assert "residual_window_s" in line and "<=" in line


@pytest.mark.parametrize(
    "extra",
    [
        '[[faults]]\nchannel = 1\nkind = "spike"\nrate_hz = 100000.0\n',
        "".join(
            f'[[faults]]\nchannel = 1\nkind = "dropout"\nstart_s = {i * 1e-4}\n'
            for i in range(2000)
        ),
    ],
    ids=["spike_rate", "2000_faults"],
)
def test_scenario_fault_bounds(tmp_path, capsys, extra):
    path = tmp_path / "sc.toml"
    path.write_text("duration_s = 1.0\n" + extra)
    line = one_error(*run_cli(capsys, "emulate", str(path), "--out", str(tmp_path / "o.log"), "-q"))
    assert "sc.toml" in line and ("rate_hz" in line or "faults" in line)


# ------------------------------------------------------- item 9: non-regular files, Ctrl-C
@pytest.mark.parametrize("ext", [".log", ".bin", ".mcap", ".asc"])
def test_fifo_log_is_refused(tmp_path, capsys, ext):
    import os

    path = tmp_path / f"pipe{ext}"
    os.mkfifo(path)
    line = one_error(*run_cli(capsys, "replay", str(path), "-q"))
    assert path.name in line and "not a regular file (a FIFO)" in line


@pytest.mark.parametrize("ext", [".log", ".bin"])
def test_dev_zero_log_is_refused(tmp_path, capsys, ext):
    path = tmp_path / f"zero{ext}"
    path.symlink_to("/dev/zero")
    line = one_error(*run_cli(capsys, "replay", str(path), "-q"))
    assert "not a regular file (a character device)" in line


def test_ctrl_c_ends_a_read_ahead_whose_reader_never_yields():
    """The prefetch thread is stuck in a read that never returns (a /dev/zero-like
    source): Ctrl-C must still end the replay at once."""
    import os
    import signal
    import threading

    from bench.replay.prefetch import prefetch

    release = threading.Event()  # ends the stuck read after the test (no thread left behind)

    def never():
        while not release.wait(0.05):
            pass
        yield from ()

    threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
    # without the fix the loop never ends: the limit is a hang guard, not a speed bound
    with time_limit(120), pytest.raises(KeyboardInterrupt):
        for _ in prefetch(never()):
            pass
    release.set()
