"""Every DuckDB example of the README and docs runs as written (issue 28: `.df()` said
"pandas is required"): each ```sql block and each ```python block that uses duckdb, in a
folder holding what the examples name, `fleet/` from a real `bench fleet` and `out.parquet`
from a real `bench replay`. The queries' answers are checked where the docs say what they
find (the logs with ch3 excluded for more than 10 s)."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

from bench.cli import main

ROOT = Path(__file__).resolve().parent.parent
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
STUCK_LOG = "train01"


def blocks(lang: str) -> list[tuple[str, str]]:
    """(where, code) of every fenced ``lang`` block that is a DuckDB example."""
    found = []
    for doc in DOCS:
        text = doc.read_text()
        for m in re.finditer(rf"^```{lang}\n(.*?)^```", text, re.S | re.M):
            code = m.group(1)
            if lang == "sql" or "duckdb" in code:
                line = text[: m.start()].count("\n") + 1
                found.append((f"{doc.name}:{line}", code))
    return found


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """fleet/ of three logs (train01 with ch3 stuck for 12 s) and out.parquet."""
    from devices.emulator import scenario_from_dict, simulate
    from devices.writers import write_candump

    d = tmp_path_factory.mktemp("docs")
    logs = d / "logs"
    logs.mkdir()
    for i, stuck in enumerate((None, 12.0, None)):
        faults = [] if stuck is None else [
            {"channel": 3, "kind": "stuck", "start_s": 1.0, "end_s": 1.0 + stuck}
        ]  # fmt: skip
        sc = {
            "seed": i,
            "duration_s": 15.0 if stuck else 2.0,
            "sample_rate_hz": 100,
            "initial_speed_mps": 10.0,
            "track": [{"length_m": 100.0, "gradient_permil": 2.0}],
            "channels": [{"angle_deg": a, "noise_mps2": 0.002} for a in (30.0, 0.0, -30.0)],
            "faults": faults,
        }
        write_candump(logs / f"train{i:02d}.log", simulate(scenario_from_dict(sc, f"d{i}")).frames)
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        argv = ["fleet", str(logs / "*.log"), "--out", str(d / "fleet"), "--workers", "1"]
        assert main(argv) == 0
        replay = ["replay", str(logs / "train00.log"), "--parquet", str(d / "out.parquet"), "-q"]
        assert main(replay) == 0
    return d


def test_the_docs_have_duckdb_examples() -> None:
    where = [w for w, _ in blocks("sql") + blocks("python")]
    assert any(w.startswith("README.md") for w in where)
    assert sum(w.startswith("FLEET.md") for w in where) >= 3
    assert any(w.startswith("RESULTS.md") for w in where)


@pytest.mark.parametrize(("where", "code"), blocks("sql"), ids=lambda v: v.split("\n")[0])
def test_sql_example_runs_as_written(
    folder: Path, monkeypatch: pytest.MonkeyPatch, where: str, code: str
) -> None:
    import duckdb

    monkeypatch.chdir(folder)
    rows = duckdb.sql(code).fetchall()
    if "excluded_ch3_s" in code or "ch3_excluded_s" in code:  # what the docs say they find
        assert [r[0].rsplit("-", 1)[0] for r in rows] == [STUCK_LOG], where


@pytest.mark.parametrize(("where", "code"), blocks("python"), ids=lambda v: v.split("\n")[0])
def test_python_example_runs_as_written(
    folder: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    where: str,
    code: str,
) -> None:
    monkeypatch.chdir(folder)
    names: dict[str, object] = {}
    exec(compile(code, where, "exec"), names)  # the doc's own code, as a reader pastes it
    shown = capsys.readouterr().out
    if "ch3_excluded_s" in code:
        assert STUCK_LOG in shown, where
    if "frame = rel.df()" in code:  # the three routes out of DuckDB agree
        frame, table, columns = names["frame"], names["table"], names["columns"]
        assert list(frame["log"]) == table.column("log").to_pylist()  # type: ignore[index, attr-defined]
        assert list(columns["log"]) == list(frame["log"])  # type: ignore[index]
