"""Outputs that would destroy inputs, and inputs that are not files (issue 27).

One rule for every command: each output is compared with each input and each other output
(same name, hard link, symlink, two names of one file not yet there) before anything is
opened; a clash is one ``bench: error:`` line naming both, exit 2, and every file is left
as it was (compared byte for byte here). Outputs are written under a temporary name and
renamed into place, so a run that fails leaves no half file and keeps what the name held.
A FIFO or a device where a file is expected is refused at once (a subprocess guards
against a hang: without the fix these tests wait on the FIFO until the guard ends them).
"""

from __future__ import annotations

import os
import resource
import subprocess
from pathlib import Path

import pytest

from bench.cli import main
from tests.helpers import bench
from tests.test_hostile_inputs import one_error

ROOT = Path(__file__).resolve().parent.parent
SCENARIO = 'description = "paths test"\nduration_s = 1.0\nseed = 2\nsample_rate_hz = 200\n'
PLAN = (
    '[plan]\ntitle = "paths"\nexpect = "pass"\n[scenario]\nduration_s = 1.0\n'
    '[[checks]]\nkind = "no_frame_loss"\n'
)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A scenario, its candump log and its MCAP, made once (copied by each test)."""
    d = tmp_path_factory.mktemp("paths")
    sc = d / "s.toml"
    sc.write_text(SCENARIO)
    assert main(["emulate", str(sc), "--out", str(d / "x.log"), "-q"]) == 0
    assert main(["emulate", str(sc), "--out", str(d / "m.mcap"), "-q"]) == 0
    return {"scenario": sc, "log": d / "x.log", "mcap": d / "m.mcap"}


@pytest.fixture
def work(tmp_path: Path, files: dict[str, Path]) -> dict[str, Path]:
    out = {}
    for key, src in files.items():
        out[key] = tmp_path / src.name
        out[key].write_bytes(src.read_bytes())
    return out


def _clash(capsys, argv: list[str], kept: list[Path], roles: tuple[str, str]) -> str:
    before = {p: p.read_bytes() for p in kept}
    line = one_error(main(argv), capsys.readouterr().err)
    for p, data in before.items():
        assert p.read_bytes() == data, f"{p} was changed"
    assert roles[0] in line and roles[1] in line, line
    return line


# -- an output naming an input ---------------------------------------------------------------
@pytest.mark.parametrize("flag", ["--csv", "--parquet"])
@pytest.mark.parametrize("log", ["log", "mcap"])
def test_replay_output_onto_its_input_is_refused(work, capsys, flag, log):
    """`bench replay X.log --csv X.log` overwrote the log; X.mcap --parquet X.mcap: SIGBUS."""
    path = work[log]
    _clash(capsys, ["replay", str(path), flag, str(path)], [path], (flag, "input log"))


@pytest.mark.parametrize("how", ["hardlink", "symlink", "relative"])
def test_replay_output_onto_its_input_by_another_name(work, capsys, how, tmp_path):
    log = work["log"]
    other = tmp_path / f"other-{how}.csv"
    if how == "hardlink":
        os.link(log, other)
    elif how == "symlink":
        other.symlink_to(log)
    else:
        other = Path(os.path.relpath(tmp_path, Path.cwd())) / ".." / tmp_path.name / log.name
    line = _clash(capsys, ["replay", str(log), "--csv", str(other)], [log], ("--csv", "input log"))
    assert str(log) in line


def test_replay_config_is_an_input_too(work, capsys, tmp_path):
    cal = tmp_path / "cal.toml"
    cal.write_text("[board]\nsample_rate_hz = 200\n")
    argv = ["replay", str(work["log"]), "--config", str(cal), "--parquet", str(cal)]
    _clash(capsys, argv, [cal, work["log"]], ("--parquet", "--config"))


@pytest.mark.parametrize("flag", ["--mcap", "--csv"])
def test_run_output_onto_its_scenario_is_refused(work, capsys, flag):
    sc = work["scenario"]
    argv = ["run", "--emulate", str(sc), flag, str(sc), "--duration", "1", "-q"]
    _clash(capsys, argv, [sc], (flag, "scenario"))


@pytest.mark.parametrize("flag", ["--out", "--truth", "--calibration-out"])
def test_emulate_output_onto_its_scenario_is_refused(work, capsys, flag):
    sc = work["scenario"]
    _clash(capsys, ["emulate", str(sc), flag, str(sc)], [sc], (flag, "scenario"))


@pytest.mark.parametrize("flag", ["--candump", "--csv", "--parquet"])
def test_log_export_onto_its_input_is_refused(work, capsys, flag):
    """`bench log export M.mcap --candump M.mcap` died with SIGBUS."""
    m = work["mcap"]
    _clash(capsys, ["log", "export", str(m), flag, str(m)], [m], (flag, "input log"))


def test_calibrate_onto_its_log_is_refused(work, capsys):
    log = work["log"]
    argv = ["calibrate", str(log), "--reference", "level", "--out", str(log)]
    _clash(capsys, argv, [log], ("--out", "log"))


def test_accept_into_the_folder_of_its_plan_is_refused(tmp_path, capsys):
    """The run writes DIR/scenario.toml: a plan saved under that name is an input."""
    plan = tmp_path / "scenario.toml"
    plan.write_text(PLAN)
    _clash(capsys, ["accept", str(plan), "--out", str(tmp_path)], [plan], ("--out", "plan"))
    assert not (tmp_path / "junit.xml").exists()


def test_tui_replay_recording_onto_the_log_replayed_is_refused(work, capsys):
    m = work["mcap"]
    _clash(capsys, ["tui", "--replay", str(m), "--mcap", str(m)], [m], ("--mcap", "--replay"))


def test_demo_recording_onto_its_scenario_is_refused(work, capsys):
    sc = work["scenario"]
    argv = ["demo", "--scenario", str(sc), "--mcap", str(sc)]
    _clash(capsys, argv, [sc], ("--mcap", "scenario"))


def test_fleet_index_onto_its_config_is_refused(work, capsys, tmp_path):
    out = tmp_path / "fleet"
    out.mkdir()
    cfg = out / "logs.parquet"
    cfg.write_text("[board]\nsample_rate_hz = 200\n")
    argv = ["fleet", str(work["log"]), "--out", str(out), "--config", str(cfg), "-q"]
    _clash(capsys, argv, [cfg], ("--out index", "--config"))


# -- two outputs naming one file ---------------------------------------------------------------
def test_run_mcap_and_csv_on_one_path_is_refused(work, capsys, tmp_path):
    """`bench run --mcap F --csv F` left a CSV and no log."""
    f = tmp_path / "F"
    argv = ["run", "--emulate", str(work["scenario"]), "--mcap", str(f), "--csv", str(f)]
    _clash(capsys, argv, [], ("--mcap", "--csv"))
    assert not f.exists()


@pytest.mark.parametrize("second", ["same", "dot-slash", "dangling-symlink"])
def test_replay_csv_and_parquet_on_one_path_is_refused(work, capsys, tmp_path, second):
    """`--csv F --parquet F` left a file that was neither."""
    f = tmp_path / "F"
    other = str(f)
    if second == "dot-slash":
        other = str(tmp_path / "." / "F")
    elif second == "dangling-symlink":
        link = tmp_path / "link"
        link.symlink_to(f)  # F does not exist yet: both names would create it
        other = str(link)
    argv = ["replay", str(work["log"]), "--csv", str(f), "--parquet", other, "-q"]
    _clash(capsys, argv, [], ("--csv", "--parquet"))
    assert not f.exists()


def test_two_outputs_to_stdout_are_refused(work, capsys):
    argv = ["replay", str(work["log"]), "--csv", "-", "--parquet", "-", "-q"]
    line = _clash(capsys, argv, [], ("--csv", "--parquet"))
    assert "stdout" in line


def test_two_outputs_to_a_device_are_fine(work, capsys):
    argv = ["replay", str(work["log"]), "--csv", "/dev/null", "--parquet", "/dev/null", "-q"]
    assert main(argv) == 0, capsys.readouterr().err


# -- outputs appear whole, or not at all -----------------------------------------------------
def test_a_failed_replay_keeps_what_the_outputs_held(work, capsys, tmp_path):
    """A log without a single frame is an error: the CSV and Parquet file that were there
    are kept as they were, and no temporary file is left."""
    bad = tmp_path / "noise.log"
    bad.write_bytes(bytes(range(256)) * 10)
    csv, pq = tmp_path / "old.csv", tmp_path / "old.parquet"
    csv.write_text("earlier results\n")
    pq.write_bytes(b"earlier parquet")
    code = main(["replay", str(bad), "--csv", str(csv), "--parquet", str(pq), "-q"])
    one_error(code, capsys.readouterr().err)
    assert csv.read_text() == "earlier results\n" and pq.read_bytes() == b"earlier parquet"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [*(p.name for p in work.values()), "noise.log", "old.csv", "old.parquet"]
    )


def test_a_replay_writes_through_a_symlinked_output(work, capsys, tmp_path):
    """A symlink given as the output stays a symlink: the file it points at is replaced."""
    target = tmp_path / "real.csv"
    target.write_text("old\n")
    link = tmp_path / "link.csv"
    link.symlink_to(target)
    assert main(["replay", str(work["log"]), "--csv", str(link), "-q"]) == 0
    assert link.is_symlink() and target.read_text().startswith("time_s,")


def test_an_interrupted_emulation_leaves_no_half_file(work, tmp_path, monkeypatch):
    """A failure part way through `bench emulate --out` leaves the name as it was."""
    from devices.emulator import stream_out

    out = tmp_path / "frames.log"
    out.write_text("the earlier run\n")

    def failing(*args, **kwargs):  # the run breaks after its first chunk is written
        for k, chunk in enumerate(chunks_of(*args, **kwargs)):
            if k == 1:
                raise KeyboardInterrupt
            yield chunk

    chunks_of = stream_out.simulate_chunks
    monkeypatch.setattr(stream_out, "simulate_chunks", failing)
    long = tmp_path / "long.toml"
    long.write_text(SCENARIO.replace("duration_s = 1.0", "duration_s = 30.0"))
    argv = ["emulate", str(long), "--out", str(out), "--truth", str(tmp_path / "t.csv")]
    assert main(argv) == 130
    assert out.read_text() == "the earlier run\n"
    assert not (tmp_path / "t.csv").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# -- inputs that are not regular files ---------------------------------------------------------
def _limited() -> None:
    # /dev/zero read as a file grows without end: 4 GB of address space ends that quickly
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))


def guarded(argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """The command in a process of its own; the timeout only ends a hang (a failure)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return bench(*argv, cwd=cwd, timeout=60, env=env, preexec_fn=_limited)


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    p = tmp_path / "pipe.toml"
    os.mkfifo(p)
    return p


def _refused(r: subprocess.CompletedProcess[str], name: str) -> None:
    line = one_error(r.returncode, r.stderr)
    assert name in line and ("FIFO" in line or "device" in line), line


@pytest.mark.parametrize("what", ["fifo", "/dev/zero"])
def test_replay_config_that_is_not_a_file_is_refused(work, fifo, what, tmp_path):
    cfg = str(fifo) if what == "fifo" else what
    _refused(guarded(["replay", str(work["log"]), "--config", cfg, "-q"], tmp_path), cfg)


@pytest.mark.parametrize("what", ["fifo", "/dev/zero"])
def test_fleet_config_that_is_not_a_file_is_refused(work, fifo, what, tmp_path):
    cfg = str(fifo) if what == "fifo" else what
    argv = ["fleet", str(work["log"]), "--out", str(tmp_path / "f"), "--config", cfg]
    _refused(guarded(argv, tmp_path), cfg)
    assert not (tmp_path / "f" / "logs.parquet").exists()


@pytest.mark.parametrize("what", ["fifo", "/dev/zero"])
def test_emulate_and_accept_of_a_device_are_refused(fifo, what, tmp_path):
    path = str(fifo) if what == "fifo" else what
    _refused(guarded(["emulate", path, "--out", str(tmp_path / "o.log")], tmp_path), path)
    _refused(guarded(["accept", path, "--out", str(tmp_path / "acc")], tmp_path), path)
    assert not (tmp_path / "acc").exists()


@pytest.mark.parametrize("what", ["fifo", "/dev/zero"])
def test_plan_whose_scenario_is_not_a_file_is_refused(fifo, what, tmp_path):
    target = str(fifo) if what == "fifo" else what
    plan = tmp_path / "plan.toml"
    plan.write_text(
        f'scenario = "{target}"\n[plan]\ntitle = "t"\nexpect = "pass"\n'
        '[[checks]]\nkind = "no_frame_loss"\n'
    )
    _refused(guarded(["accept", str(plan), "--out", str(tmp_path / "acc")], tmp_path), target)


def test_steps_file_that_is_a_fifo_is_refused(fifo, tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)
    argv = ["accept", str(plan), "--out", str(tmp_path / "acc"), "--steps", str(fifo)]
    _refused(guarded(argv, tmp_path), str(fifo))


@pytest.mark.parametrize(
    "argv",
    [
        ["log", "info"],
        ["log", "export", "--csv", "out.csv"],
        ["replay", "--csv", "out.csv"],
        ["calibrate", "--out", "cal.toml"],
        ["play", "-i", "virtual", "-c", "hostile-paths"],
    ],
    ids=lambda a: " ".join(a[:2]),
)
def test_an_mcap_log_that_is_a_fifo_is_refused(tmp_path, argv):
    """`bench log info` and `bench log export` of a FIFO waited for a writer forever."""
    pipe = tmp_path / "pipe.mcap"
    os.mkfifo(pipe)
    r = guarded(
        [*argv[:2], str(pipe), *argv[2:]] if argv[0] == "log" else [argv[0], str(pipe), *argv[1:]],
        tmp_path,
    )
    _refused(r, str(pipe))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe.mcap"]  # nothing written


@pytest.mark.parametrize("argv", [["log", "info"], ["log", "export", "--csv"]])
def test_log_info_and_export_of_a_device_are_refused(tmp_path, argv):
    """/dev/zero was read as an empty MCAP file: exit 0, and export wrote a 0-row CSV."""
    out = [str(tmp_path / "out.csv")] if argv[-1] == "--csv" else []
    r = guarded([*argv[:2], "/dev/zero", *argv[2:], *out], tmp_path)
    _refused(r, "/dev/zero")
    assert not list(tmp_path.iterdir())


def test_a_truth_csv_that_fails_part_way_leaves_the_name_as_it_was(tmp_path, monkeypatch):
    """`bench emulate --realtime --truth T` wrote T in place: a failure left half a file."""
    import numpy as np

    from devices.emulator import player, stream_out

    out = tmp_path / "truth.csv"
    out.write_text("the earlier truth\n")

    def failing(f, truth, header):  # the header and a row, then the disk is full
        f.write(b"t_s,...\n0.0,...\n")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(stream_out, "write_truth_rows", failing)
    with pytest.raises(player.BenchError, match="No space left"):
        player.write_truth_csv(out, np.zeros(3))
    assert out.read_text() == "the earlier truth\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["truth.csv"]


def test_a_reference_table_that_is_a_fifo_is_named_for_what_it_is(work, tmp_path):
    """`bench calibrate --reference pipe.csv` said "table file not found" of a FIFO."""
    pipe = tmp_path / "steps.csv"
    os.mkfifo(pipe)
    argv = ["calibrate", str(work["mcap"]), "--reference", str(pipe), "--out", "cal.toml"]
    _refused(guarded(argv, tmp_path), str(pipe))
    assert not (tmp_path / "cal.toml").exists()


@pytest.mark.parametrize("what", ["fifo", "folder"])
def test_a_defaults_file_that_is_not_a_file_is_an_error(work, tmp_path, what):
    """A bench.toml that was a FIFO or a folder was passed over without a word."""
    local = tmp_path / "bench.toml"
    os.mkfifo(local) if what == "fifo" else local.mkdir()
    r = guarded(["replay", str(work["log"]), "--csv", os.devnull, "-q"], tmp_path)
    line = one_error(r.returncode, r.stderr)
    assert str(local) in line and "cannot read defaults" in line, line
    assert ("FIFO" if what == "fifo" else "folder") in line
