"""``bench log info`` / ``bench log export`` on real files, and the MCAP paths of
``bench replay --compare`` and ``bench emulate --out FILE.mcap``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.config import Config
from bench.mcaplog.info import spans
from bench.mcaplog.sink import McapSink
from tests.test_mcap_roundtrip import csv_text
from tests.test_mcap_support import run_pipeline, synthetic_stream


@pytest.fixture(scope="module")
def run_file(tmp_path_factory: pytest.TempPathFactory):
    stream = synthetic_stream(seconds=3.0)
    path = tmp_path_factory.mktemp("cli") / "run.mcap"
    cfg = Config()
    sink = McapSink(path, cfg, {"source": "cli test"}, [("cal.toml", cfg.to_toml().encode())])
    results, _ = run_pipeline(stream.batches, cfg, [sink])
    sink.close()
    return stream, path, results


def test_spans() -> None:
    m = np.array([0, 1, 1, 0, 1, 0, 0, 1], bool)
    assert spans(m) == [(1, 3), (4, 5), (7, 8)]
    assert spans(np.zeros(3, bool)) == [] and spans(np.ones(2, bool)) == [(0, 2)]


def test_log_info_text(run_file, capsys) -> None:
    stream, path, results = run_file
    assert main(["log", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "complete" in out
    for cid, n in stream.counts_by_id().items():
        assert f"id 0x{cid:03X}:   {n}" in out
    assert f"frames:      {len(stream.frames)}" in out
    assert "CRC_MISMATCH" in out and "WRONG_DLC" in out and "UNKNOWN_ID" in out
    assert "COBS_ERROR" in out and "disconnect 1" in out
    assert "vote-failure spans:" in out and "invalid spans:" in out
    assert "source = cli test" in out and "cal.toml" in out
    assert f"results:     {len(results)}" in out


def test_log_info_json_and_verify(run_file, capsys) -> None:
    stream, path, results = run_file
    assert main(["log", "info", str(path), "--json", "--verify"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames"] == len(stream.frames)
    assert info["frames_by_id"] == {
        f"0x{k:03X}": v for k, v in sorted(stream.counts_by_id().items())
    }
    assert info["crc_problems"] == []
    assert sum(info["link_errors"].values()) == len(stream.link_errors)
    assert info["uart_frames"] == int(np.count_nonzero(stream.frames["flags"] & 0x10))
    invalid = ~results["valid"]
    assert info["invalid"]["samples"] == int(invalid.sum())
    assert info["invalid"]["count"] == len(spans(invalid))
    fails = ~results["votes"].all(axis=1)
    assert info["vote_failures"]["count"] == len(spans(fails)) > 0
    first = info["vote_failures"]["spans"][0]
    a, b = spans(fails)[0]
    assert (first["first_n"], first["samples"]) == (int(results["n"][a]), b - a)
    assert abs(info["duration_s"] - 3.0) < 0.01


def test_export_csv_is_the_live_csv(run_file, tmp_path: Path, capsys) -> None:
    _, path, results = run_file
    out = tmp_path / "out.csv"
    assert main(["log", "export", str(path), "--csv", str(out)]) == 0
    assert out.read_text() == csv_text(results)
    again = tmp_path / "again.csv"
    assert main(["log", "export", str(path), "--csv", str(again), "--recompute"]) == 0
    assert again.read_text() == csv_text(results)


def test_export_candump_reads_back(run_file, tmp_path: Path) -> None:
    from devices.formats import open_log

    stream, path, _ = run_file
    out = tmp_path / "frames.log"
    assert main(["log", "export", str(path), "--candump", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert len(lines) == len(stream.frames)
    assert lines[0].startswith("(") and " can0 " in lines[0]
    assert any(" uart0 " in line for line in lines)
    back = np.concatenate([b.frames for b in open_log(out).batches()])
    assert np.array_equal(back["id"], stream.frames["id"])
    assert np.array_equal(back["dlc"], stream.frames["dlc"])
    assert np.array_equal(back["data"], stream.frames["data"])
    assert np.array_equal(back["t"], stream.frames["t"])  # whole microseconds: exact


def test_replay_compare(run_file, tmp_path: Path, capsys) -> None:
    _, path, _ = run_file
    assert main(["replay", str(path), "--compare", "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "compare: identical" in captured.out + captured.err
    cal = tmp_path / "tilted.toml"
    cal.write_text("".join(f"[[channels]]\nangle_deg = {a}\n" for a in (30.5, 0.0, -30.0)))
    assert main(["replay", str(path), "--compare", "--quiet", "--config", str(cal)]) == 1
    captured = capsys.readouterr()
    out = captured.out + captured.err
    assert "DIFFERENT" in out and "valid (device)" in out
    assert f"after:  file {cal}" in out


def test_emulate_out_mcap_and_log_replay_identically(tmp_path: Path) -> None:
    scenario = Path(__file__).resolve().parents[1] / "devices" / "scenarios" / "link_faults.toml"
    text = scenario.read_text().replace("duration_s = 60.0", "duration_s = 32.0")
    short = tmp_path / "short.toml"
    short.write_text(text)
    for suffix in ("mcap", "log"):
        assert main(["emulate", str(short), "--out", str(tmp_path / f"run.{suffix}")]) == 0
        assert (
            main(
                [
                    "replay",
                    str(tmp_path / f"run.{suffix}"),
                    "--csv",
                    str(tmp_path / f"{suffix}.csv"),
                    "-q",
                ]
            )
            == 0
        )
    a, b = (tmp_path / "mcap.csv").read_text(), (tmp_path / "log.csv").read_text()
    assert a == b and a.count("\n") > 3000
    out = tmp_path / "recomputed.csv"  # no results recorded in an emulator file: recomputed
    assert main(["log", "export", str(tmp_path / "run.mcap"), "--csv", str(out)]) == 0
    assert out.read_text() == a


def test_missing_file_is_one_line_error(tmp_path: Path, capsys) -> None:
    assert main(["log", "info", str(tmp_path / "nope.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench: error:") and err.count("\n") == 1
