"""A secondary output (the live CSV) failing mid-run, and output-path mistakes (issue 16, 1-2).

A full disk under ``--csv`` must not stop a live run: the CSV is isolated (an event, a
status-line flag, one error line and a non-zero exit at the end) while the pipeline and the
MCAP log go on, every frame received logged. Output paths are checked before anything
starts; a write that fails later is a one-line error. The full disk is made two ways: a
stream that refuses bytes past a limit with ENOSPC (always), and a real 64 kB tmpfs (when
the tests run as root and may mount one).
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import subprocess
from pathlib import Path

import pyarrow as pa
import pytest

from bench.cli import main
from tests.helpers import bench, event_texts

SCENARIO = """
description = "output test: 200 Hz, 2.5 s, level"
seed = 4
duration_s = 2.5
sample_rate_hz = 200
"""


class FullDisk(io.RawIOBase):
    """A file that takes ``limit`` bytes, then refuses every write with ENOSPC."""

    def __init__(self, path: str, limit: int) -> None:
        self._f = open(path, "wb")  # noqa: SIM115 - closed in close()
        self.limit, self.n = limit, 0

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:  # type: ignore[override]
        if self.n + len(b) > self.limit:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.n += len(b)
        return self._f.write(b)

    def close(self) -> None:
        self._f.close()
        super().close()


@pytest.fixture
def scenario(tmp_path: Path) -> Path:
    p = tmp_path / "out_test.toml"
    p.write_text(SCENARIO, encoding="utf-8")
    return p


def _frames_sent(scenario: Path) -> int:
    from devices.emulator import load_scenario, simulate

    return len(simulate(load_scenario(scenario)).frames)


def _log_info(path: Path, capsys) -> dict:
    capsys.readouterr()
    assert main(["log", "info", str(path), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_live_csv_on_a_full_disk_is_isolated_and_the_mcap_goes_on(
    tmp_path, scenario, monkeypatch, capsys
):
    from bench.sinks import tables as table_sinks

    limit = 20_000  # ~60 rows: the disk fills at the first write, 0.5 s into the run
    monkeypatch.setattr(
        table_sinks, "open_stream", lambda t: pa.PythonFile(FullDisk(str(t), limit), mode="w")
    )
    out, log = tmp_path / "live.csv", tmp_path / "run.mcap"
    code = main(["run", "--emulate", str(scenario), "--csv", str(out), "--mcap", str(log)])
    err = capsys.readouterr().err
    assert code == 1
    assert f"bench: error: {out}: cannot write the CSV: No space left on device" in err
    assert f"bench: error: {out}: not written (" in err  # never half a file under its name
    assert f"bench log export {log} --csv {out}" in err
    assert "Traceback" not in err
    assert "CSV FAILED" in err  # the status line's flag
    assert f"bench: log written: {log}" in err
    # the pipeline and the MCAP went on: every frame the board sent was received and logged
    sent = _frames_sent(scenario)
    info = _log_info(log, capsys)
    assert info["frames"] == sent, info["frames"]
    assert any(e.startswith("OUTPUT_ERROR No space left on device") for e in event_texts(log))
    # the failed CSV is removed, not left cut short; the command the error gives makes it
    assert not out.exists() and not list(tmp_path.glob(".live*"))
    replayed = tmp_path / "replay.csv"
    monkeypatch.undo()
    assert main(["replay", str(log), "--csv", str(replayed), "-q"]) == 0
    assert main(["log", "export", str(log), "--csv", str(out)]) == 0
    assert out.read_text() == replayed.read_text()


def _can_mount_tmpfs(where: Path) -> bool:
    if os.geteuid() != 0:
        return False
    where.mkdir()
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(where)], capture_output=True
    )
    return r.returncode == 0


def test_live_csv_on_a_real_full_tmpfs(tmp_path, scenario):
    small = tmp_path / "small"
    if not _can_mount_tmpfs(small):
        pytest.skip("needs root and mount to make a 64 kB tmpfs")
    try:
        log = tmp_path / "run.mcap"
        r = bench("run", "--emulate", str(scenario), "--csv", str(small / "live.csv"),
                  "--mcap", str(log))  # fmt: skip
        assert r.returncode == 1, r.stderr
        assert "cannot write the CSV: No space left on device" in r.stderr
        assert "Traceback" not in r.stderr
        info = bench("log", "info", str(log), "--json")
        assert json.loads(info.stdout)["frames"] == _frames_sent(scenario)
    finally:
        with contextlib.suppress(Exception):
            subprocess.run(["umount", str(small)], check=False)


# -- output paths checked before the run starts ----------------------------------------------
def _missing(tmp_path: Path) -> str:
    return str(tmp_path / "no-such-folder" / "x.csv")


@pytest.mark.parametrize(
    ("target", "message"),
    [
        (_missing, "folder {tmp}/no-such-folder does not exist"),
        (lambda tmp: str(tmp), "it is a folder"),
        (lambda tmp: "/dev/full", "cannot write the CSV: No space left on device"),
    ],
    ids=["missing-folder", "a-folder", "dev-full"],
)
def test_replay_csv_to_a_bad_path_is_one_line(tmp_path, capsys, target, message):
    from devices.writers import write_candump
    from tests.test_mcap_support import emulated

    log = tmp_path / "in.log"
    write_candump(log, emulated(2.0, faults=False).frames)
    capsys.readouterr()
    assert main(["replay", str(log), "--csv", target(tmp_path), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench: error: ") and err.count("\n") == 1, err
    assert message.format(tmp=tmp_path) in err


def test_replay_parquet_to_dev_full_is_one_line(tmp_path, capsys):
    from devices.writers import write_candump
    from tests.test_mcap_support import emulated

    log = tmp_path / "in.log"
    write_candump(log, emulated(2.0, faults=False).frames)
    capsys.readouterr()
    assert main(["replay", str(log), "--parquet", "/dev/full", "-q"]) == 2
    err = capsys.readouterr().err
    why = "cannot write the Parquet file: No space left on device"
    assert err == f"bench: error: /dev/full: {why}\n"


def test_run_csv_into_a_missing_folder_stops_before_anything_starts(tmp_path, scenario, capfd):
    log = tmp_path / "run.mcap"
    code = main(
        ["run", "--emulate", str(scenario), "--csv", "/nonexistent/x.csv", "--mcap", str(log)]
    )
    err = capfd.readouterr().err
    assert code == 2
    assert err == (
        "bench: error: /nonexistent/x.csv: cannot write the CSV: "
        "folder /nonexistent does not exist\n"
    )
    assert not log.exists()  # no empty MCAP left behind
    assert "VirtualBus" not in err


@pytest.fixture(scope="module")
def run_log(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("outlog")
    sc = d / "s.toml"
    sc.write_text(SCENARIO, encoding="utf-8")
    log = d / "run.mcap"
    assert main(["run", "--emulate", str(sc), "--mcap", str(log), "-q"]) == 0
    return log


@pytest.mark.parametrize("flag", ["--candump", "--csv", "--parquet"])
def test_log_export_to_dev_full_is_one_line(run_log, capsys, flag):
    capsys.readouterr()
    assert main(["log", "export", str(run_log), flag, "/dev/full"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench: error: /dev/full: cannot write") and err.count("\n") == 1, err
    assert "No space left on device" in err


@pytest.mark.parametrize("flag", ["--candump", "--csv", "--parquet"])
def test_log_export_into_a_missing_folder_is_one_line(run_log, tmp_path, capsys, flag):
    capsys.readouterr()
    out = tmp_path / "nope" / "x.out"
    assert main(["log", "export", str(run_log), flag, str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err, err


def test_log_export_parquet_holds_the_recorded_results(run_log, tmp_path):
    import pyarrow.parquet as pq

    from bench.mcaplog.recorded import read_results
    from bench.records.columns import results_from_table

    out = tmp_path / "x.parquet"
    assert main(["log", "export", str(run_log), "--parquet", str(out)]) == 0
    recorded = read_results(run_log)
    assert len(recorded) > 300
    assert results_from_table(pq.read_table(out)).tobytes() == recorded.tobytes()


def test_accept_out_on_a_full_disk_is_an_error_not_a_fail(tmp_path, capsys, monkeypatch):
    """Writing junit.xml fails with ENOSPC: exit 2 (error) with one line, not exit 1 (fail)."""
    real = Path.write_bytes

    def full(self: Path, data: bytes) -> int:
        if "junit" in self.name:  # junit.xml is written as .junit.partial-*.xml, renamed
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", full)
    out = tmp_path / "acc"
    code = main(["accept", "fault-counter-jump", "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.splitlines()[-1] == (
        f"bench: error: {out}: cannot write the acceptance results: No space left on device"
    )
    assert "Traceback" not in err
    assert not (out / "junit.xml").exists() and not list(out.glob(".junit*"))


def test_accept_out_that_is_a_file_stops_before_the_run(tmp_path, capsys):
    out = tmp_path / "taken"
    out.write_text("x")
    assert main(["accept", "fault-counter-jump", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    why = "cannot write the acceptance results there: it is not a folder"
    assert err == f"bench: error: {out}: {why}\n"
