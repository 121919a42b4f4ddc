"""`bench replay --mcap OUT` (and with --smooth, issue 26): the replay as an MCAP log whose
results carry the smoother's columns.

Expectations are independent of the MCAP writer: the replay's own Parquet file of the
same run (another writer), the emulator's wheel-diameter error, @mcap/core's reading of
the file (tests/js/check_mcap.mjs, what Foxglove uses), and the file replayed again
(`--compare`: its recorded results are the ones a fresh pipeline computes, bit for bit).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from mcap.reader import make_reader

from bench.cli import main
from bench.mcaplog import schemas as S
from tests.mcap_js import McapJs, install
from tests.test_replay_smooth import SCENARIO, WHEEL, emulate_run

NEW = ("gradient_smoothed", "gradient_smoothed_sigma", "model_e", "model_e_sigma", "model_b1")


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = emulate_run(tmp_path_factory.mktemp("replay_mcap"), SCENARIO)
    replay = ["replay", str(d / "run.log"), "--config", str(d / "cal.toml"), "-q"]
    smooth = ["--smooth", "--mcap", str(d / "s.mcap"), "--parquet", str(d / "s.pq")]
    smooth += ["--csv", str(d / "s.csv")]
    assert main([*replay, *smooth]) == 0
    assert main([*replay, "--mcap", str(d / "plain.mcap")]) == 0
    return d


def _results(path: Path) -> tuple[dict[str, object], list[dict[str, object]]]:
    with path.open("rb") as f:
        reader = make_reader(f)
        schema = None
        rows = []
        for sch, _ch, msg in reader.iter_messages(topics=[S.RESULT_TOPIC]):
            schema = json.loads(sch.data)
            rows.append(json.loads(msg.data))
    assert schema is not None
    return schema, rows


def test_smoothed_results_messages_carry_the_parquet_s_values(run: Path) -> None:
    schema, rows = _results(run / "s.mcap")
    table = pq.read_table(run / "s.pq")
    assert len(rows) == table.num_rows == 7000
    props = schema["properties"]
    assert isinstance(props, dict)
    for name in NEW:
        assert name in props, name
    assert "wheel_diameter_error_smoothed" in props["model_e"]["description"]
    pairs = (
        ("gradient_smoothed", "gradient_smoothed_permil"),
        ("gradient_smoothed_sigma", "gradient_smoothed_sigma_permil"),
        ("model_e", "wheel_diameter_error_smoothed"),
        ("model_b2_sigma", "bias2_smoothed_sigma_mps2"),
        ("gradient_signed", "gradient_signed_permil"),
    )
    for field, column in pairs:
        col = table[column].to_pylist()
        for i in (0, 3500, 6999):
            want = col[i]
            got = rows[i][field]
            assert got == want or (got is None and (want is None or math.isnan(want))), field
    # the emulator's truth: the wheel reads 2 % high
    e = [r["model_e"] for r in rows[::500]]
    sig = rows[0]["model_e_sigma"]
    assert isinstance(sig, float)
    assert all(isinstance(x, float) and abs(x - WHEEL) <= 2.0 * sig for x in e)


def test_without_smooth_the_results_are_the_live_schema_s(run: Path) -> None:
    schema, rows = _results(run / "plain.mcap")
    assert schema == S.RESULT_SCHEMA
    assert not set(NEW) & set(rows[0])


def test_the_replay_s_log_replays_to_its_recorded_results(run: Path) -> None:
    for name in ("s.mcap", "plain.mcap"):
        assert main(["replay", str(run / name), "--compare", "-q"]) == 0, name


def test_the_smoothed_log_conforms_to_mcap_core(run: Path) -> None:
    mcap_js: McapJs = install()
    report = mcap_js.check(run / "s.mcap")
    channels = {c["topic"]: c for c in report["channels"]}
    res = channels[S.RESULT_TOPIC]
    assert res["count"] == 7000 and res["schemaName"] == "acb3.bench.Result"
    first = res["first"]["value"]
    assert set(NEW) <= set(first)
    assert abs(first["model_e"] - WHEEL) < 0.005
    assert report["dataSectionCrc"] == "ok"


def test_a_clashing_mcap_path_is_refused(run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["replay", str(run / "run.log"), "--mcap", str(run / "run.log"), "-q"]
    assert main(args) == 2
    assert capsys.readouterr().err.startswith("bench: error:")


def test_an_mcap_that_cannot_be_written_leaves_no_csv(
    run: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    csv = run / "alone.csv"
    args = ["replay", str(run / "run.log"), "--csv", str(csv), "-q"]
    assert main([*args, "--mcap", str(run / "no-such-folder" / "x.mcap")]) == 2
    assert capsys.readouterr().err.startswith("bench: error: cannot write the MCAP log")
    assert not csv.exists() and not list(run.glob(".alone.partial*"))


def test_log_export_of_a_smoothed_log_is_the_smoothed_replay_s_csv(run: Path) -> None:
    """The recorded smoother's columns are exported, not dropped: byte for byte the CSV the
    replay wrote beside the log."""
    assert main(["log", "export", str(run / "s.mcap"), "--csv", str(run / "export.csv")]) == 0
    assert (run / "export.csv").read_bytes() == (run / "s.csv").read_bytes()
