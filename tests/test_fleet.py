"""`bench fleet` on a 2-worker LocalCluster of processes (127.0.0.1, no dashboard).

20 small emulated logs, one of them corrupt: 20 rows in logs.parquet (one with its error),
every log's rows in results/ equal to its own `bench replay`, a re-run that skips what is
done, and the README's DuckDB question answered the same way from results/ (a window query
over every row) and from logs.parquet (the fleet's own per-log figure).
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from bench.cli import main
from bench.config import Config
from bench.records.columns import results_from_table
from bench.replay.run import replay
from devices.formats import open_log
from devices.writers import write_candump

N_LOGS = 20
STUCK = {3: 12.0, 7: 11.0}  # log index -> seconds of ch3 stuck (excluded for ~ that long)


def _scenario(seed: int, seconds: float, stuck_s: float | None) -> dict:
    faults = []
    if stuck_s is not None:
        faults.append({"channel": 3, "kind": "stuck", "start_s": 1.0, "end_s": 1.0 + stuck_s})
    return {
        "seed": seed,
        "duration_s": seconds,
        "sample_rate_hz": 100,
        "initial_speed_mps": 10.0,
        "track": [{"length_m": 100.0, "gradient_permil": float(seed)}],
        "channels": [{"angle_deg": a, "noise_mps2": 0.002} for a in (30.0, 0.0, -30.0)],
        "faults": faults,
    }


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> tuple[Path, list[Path], int, str]:
    from devices.emulator import scenario_from_dict, simulate

    d = tmp_path_factory.mktemp("fleet")
    logs = []
    for i in range(N_LOGS):
        stuck = STUCK.get(i)
        sc = _scenario(i, 15.0 if stuck else 2.0, stuck)
        frames = simulate(scenario_from_dict(sc, f"fleet-{i}")).frames
        path = d / "logs" / f"train{i:02d}.log"
        path.parent.mkdir(exist_ok=True)
        write_candump(path, frames)
        logs.append(path)
    corrupt = d / "logs" / "train99.mcap"
    corrupt.write_bytes(bytes(range(256)) * 8)  # not an MCAP file at all
    logs[5] = corrupt  # 20 logs, one of them corrupt
    (d / "logs" / "train05.log").unlink()
    out = d / "out"
    import contextlib

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["fleet", str(d / "logs" / "*"), "--out", str(out), "--workers", "2"])
    return out, logs, code, err.getvalue()


def test_fleet_writes_one_row_per_log_and_one_error(fleet):
    out, logs, code, err = fleet
    assert code == 1, err  # one log failed
    table = pq.read_table(out / "logs.parquet")
    assert table.num_rows == N_LOGS
    rows = {Path(r["path"]).name: r for r in table.to_pylist()}
    assert set(rows) == {p.name for p in logs}
    failed = [r for r in rows.values() if r["error"]]
    assert [Path(r["path"]).name for r in failed] == ["train99.mcap"]
    assert "MCAP" in failed[0]["error"] and failed[0]["frames"] is None
    assert "Traceback" not in err
    assert "20 logs on 2 workers: 19 replayed, 0 skipped" in " ".join(err.split())


def test_fleet_results_per_log_equal_each_logs_own_replay(fleet):
    out, logs, _, _ = fleet
    table = pq.read_table(out / "logs.parquet")
    by_path = {Path(r["path"]).name: r for r in table.to_pylist()}
    dataset = ds.dataset(out / "results", format="parquet", partitioning="hive")
    names = np.asarray(dataset.to_table(columns=["log"]).column("log"))
    counts = dict(zip(*np.unique(names, return_counts=True), strict=True))
    for path in logs:
        row = by_path[path.name]
        if row["error"]:
            assert row["log"] not in counts
            continue
        source = open_log(str(path))
        try:
            single = replay(source, Config()).results
        finally:
            source.close()
        assert counts[row["log"]] == len(single) == row["result_rows"], path.name
        assert row["samples"] == len(single)
    # and one log bit for bit
    row = by_path["train07.log"]
    part = pq.read_table(out / "results" / f"log={row['log']}" / "part-0.parquet")
    source = open_log(str(out.parent / "logs" / "train07.log"))
    try:
        single = replay(source, Config()).results
    finally:
        source.close()
    assert results_from_table(part).tobytes() == single.tobytes()


def _readme_query(out: Path) -> str:
    """The SQL of the README's DuckDB example, pointed at ``out`` instead of ``fleet/``."""
    readme = (Path(__file__).resolve().parent.parent / "README.md").read_text()
    m = re.search(r'duckdb\.sql\("""(.*?)"""\)', readme, re.S)
    assert m, "the README's DuckDB example is gone"
    return m.group(1).replace("'fleet/", f"'{out}/")


def test_duckdb_query_of_the_readme_finds_the_logs_with_ch3_excluded(fleet):
    import duckdb

    out, _, _, _ = fleet
    con = duckdb.connect()
    got = sorted(con.execute(_readme_query(out)).fetchall())  # over every result row
    names = [f"train{i:02d}" for i in sorted(STUCK)]
    assert [log.rsplit("-", 1)[0] for log, _ in got] == names
    for (_, seconds), i in zip(got, sorted(STUCK), strict=True):
        assert STUCK[i] - 1.0 < seconds < STUCK[i] + 1.0  # excluded ~0.5 s after it stuck
    # the same question from the per-log table
    per_log = con.execute(
        f"SELECT log, excluded_ch3_s FROM '{out}/logs.parquet' "
        "WHERE excluded_ch3_s > 10 ORDER BY log"
    ).fetchall()
    assert [log for log, _ in per_log] == [log for log, _ in got]
    for (_, a), (_, b) in zip(per_log, got, strict=True):
        assert round(a, 1) == b


def test_fleet_rerun_skips_logs_already_done(fleet, tmp_path):
    out, logs, _, _ = fleet
    before = pq.read_table(out / "logs.parquet").to_pylist()
    err = io.StringIO()
    import contextlib

    with contextlib.redirect_stderr(err):
        code = main(["fleet", *[str(p) for p in logs[:4]], "--out", str(out), "--workers", "1"])
    assert code == 0, err.getvalue()
    assert "4 logs on 1 workers: 0 replayed, 4 skipped" in " ".join(err.getvalue().split())
    after = pq.read_table(out / "logs.parquet").to_pylist()
    assert len(after) == N_LOGS  # the other 16 are kept
    key = {r["log"]: r for r in before}
    for r in after:
        assert r["wall_s"] == key[r["log"]]["wall_s"] or r["error"]  # nothing re-replayed


def test_piped_fleet_table_keeps_every_column_whole(fleet, capsys, monkeypatch):
    """Issue 28: `bench fleet ... | less` cut the columns to "fram..." at rich's 80 columns;
    without a terminal the table takes its natural width."""
    out, logs, _, _ = fleet
    monkeypatch.delenv("COLUMNS", raising=False)
    main(["fleet", *[str(p) for p in logs[:2]], "--out", str(out), "--workers", "1"])
    printed = capsys.readouterr().out
    header = next(line for line in printed.splitlines() if "log" in line and "frames" in line)
    for name in ("frames", "valid %", "excluded s ch1/2/3", "|ref-est| permil", "status"):
        assert name in header
    assert "…" not in printed and "train00.log" in printed


def test_a_folder_stands_for_every_log_under_it(tmp_path):
    """`bench fleet logs/` takes each log under the folder at any depth, by extension, in
    sorted order, once; other files are not logs; a folder with no log matches nothing."""
    from bench.fleet.run import expand

    for name in ("b.log", "a.mcap", "sub/c.blf", "sub/deep/d.asc", "notes.txt", "x.parquet"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "empty").mkdir()
    got = [Path(p).relative_to(tmp_path).as_posix() for p in expand([str(tmp_path)])]
    assert got == ["a.mcap", "b.log", "sub/c.blf", "sub/deep/d.asc"]
    # a file named both directly and through its folder is replayed once
    assert len(expand([str(tmp_path / "b.log"), str(tmp_path)])) == 4
    assert expand([str(tmp_path / "empty")]) == []


def test_fleet_of_a_folder_with_no_log_is_one_error(tmp_path, capsys):
    (tmp_path / "readme.txt").write_text("no logs here")
    assert main(["fleet", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bench: error: no logs match") and err.count("\n") == 1


def test_fleet_smooth_writes_the_smoothed_columns_of_replay_smooth(fleet, tmp_path):
    from bench.replay.smooth import smoothing_pass

    _, logs, _, _ = fleet
    two = [p for p in logs if p.suffix == ".log"][:2]
    out = tmp_path / "smoothed"
    args = ["fleet", *map(str, two), "--out", str(out), "--workers", "2", "--smooth", "-q"]
    assert main(args) == 0
    rows = {Path(r["path"]).name: r for r in pq.read_table(out / "logs.parquet").to_pylist()}
    for log in two:
        row = rows[log.name]
        assert row["smoothed"] is True
        assert row["wheel_diameter_error_sigma"] > 0.0
        got = pq.read_table(out / "results" / f"log={row['log']}" / "part-0.parquet")
        source = open_log(log)
        try:
            want = smoothing_pass(source, Config())
        finally:
            source.close()
        for name, values in (
            ("gradient_smoothed_permil", want.smoothed),
            ("gradient_smoothed_sigma_permil", want.smoothed_sigma),
        ):
            col = got[name].to_numpy(zero_copy_only=False)  # nulls -> NaN
            assert col.tobytes() == values.tobytes(), name
        # logs.parquet's per-log estimates are the medians of the log's per-sample columns
        for column in ("bias1_smoothed_mps2", "bias3_smoothed_mps2", "body_pitch_smoothed_rad"):
            sigma = column.replace("_smoothed_", "_smoothed_sigma_")
            x = got[column].to_numpy(zero_copy_only=False)
            assert row[sigma] > 0.0
            assert abs(row[column] - float(np.median(x))) <= 0.01 * row[sigma], column
