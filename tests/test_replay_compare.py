"""``bench replay run.mcap --compare --config NEW --plan PLAN`` answers "would this run have
passed with other angles?" in one table that fits 80 columns (issue 18)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.cli import main


@pytest.fixture(scope="module")
def level_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("accept") / "level"
    assert main(["accept", "level", "--out", str(out), "--no-plots"]) == 0
    return out / "run.mcap"


def rows(text: str) -> dict[str, list[str]]:
    """Table rows by label: the cells right of the label (split on 2+ spaces)."""
    import re

    out = {}
    for line in text.splitlines():
        cells = [c for c in re.split(r"\s{2,}", line.strip()) if c]
        if len(cells) >= 2:
            out[cells[0]] = cells[1:]
    return out


def test_compare_with_a_plan_gives_validity_and_every_verdict_both_ways_in_80_columns(
    level_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.setenv("COLUMNS", "80")
    tilted = tmp_path / "tilted.toml"
    # ch1 0.3 deg off: ~5 permil of pair error against a 1 permil vote tolerance
    tilted.write_text("[[channels]]\nangle_deg = 30.3\n[[channels]]\n[[channels]]\n")
    code = main(["replay", str(level_run), "--compare", "--config", str(tilted), "--plan", "level"])
    assert code == 1  # the results differ
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0].startswith("before: ") and lines[1].startswith("after: ")  # (a long path)
    assert max(len(line) for line in lines[2:]) <= 80
    # before/after, title + blank + header + rule, 10 figures, blank, 9 checks, blank, the
    # plan, blank, the compare line: no row wrapped onto a second line
    assert len(lines) == 2 + 4 + 10 + 1 + 9 + 1 + 1 + 1 + 1
    assert out.count("would this run have passed") == 1  # one table
    table = rows(out)
    assert table["angles ch1/ch2/ch3, deg"] == ["30/0/-30", "30.3/0/-30"]
    assert table["valid (device)"][1] == "0.00 %"  # no vote within tolerance any more
    assert float(table["valid (device)"][0].split()[0]) > 50.0
    # every check of the plan on one line, with its verdict before and after
    before, after = table["bench estimator at standstill"]
    assert before.startswith("PASS") and after.startswith("FAIL"), (before, after)
    # on the move the drift copies (docs/ESTIMATOR.md) find ch1 at odds with the odometer
    # and give the gradient from ch2 and ch3, which the wrong angle does not touch; at rest
    # nothing tells ch1 from ch3 (above)
    before, after = table["bench estimator at cruise"]
    assert before.startswith("PASS") and after.startswith("PASS"), (before, after)
    assert table["no frame lost"] == ["PASS 0 frames", "PASS 0 frames"]  # not calibration
    assert table["plan level (expects pass)"] == ["PASS", "FAIL"]
    assert "before: recorded in run.mcap (scenario of plan level as built)" in out
    assert f"after:  file {tilted}" in out


def test_compare_without_a_new_config_is_identical_both_ways(
    level_run: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    monkeypatch.setenv("COLUMNS", "80")
    assert main(["replay", str(level_run), "--compare", "--plan", "level", "-q"]) == 0
    out = capsys.readouterr().out
    table = rows(out)
    assert table["valid (device)"][0] == table["valid (device)"][1]
    assert table["plan level (expects pass)"] == ["PASS", "PASS"]
    assert "compare: identical" in out


def test_plan_needs_compare(level_run: Path, capsys) -> None:
    assert main(["replay", str(level_run), "--plan", "level"]) == 2
    assert "--plan judges a plan's checks both ways: it needs --compare" in capsys.readouterr().err


def record_foreign_run(path: Path, dropped: int) -> None:
    """A recorded run that is not plan level's: 4 s of another scenario through the
    pipeline into an MCAP file, with ``dropped`` frames recorded as lost by the acquisition
    queue (the DROPPED event a live runner writes)."""
    from bench.acceptance.feeds import can_batches
    from bench.config import Config
    from bench.mcaplog.sink import McapSink
    from bench.pipeline.steps import Pipeline, StepOutput
    from bench.records.events import EventKind, make_events
    from bench.replay.run import run_steps
    from devices.emulator import scenario_from_dict, simulate

    sim = simulate(
        scenario_from_dict({"seed": 5, "duration_s": 4.0, "sample_rate_hz": 200}, "foreign")
    )
    config = Config(sample_rate_hz=200)
    sink = McapSink(path, config, {"source": "a foreign board"})
    try:
        for step in run_steps(Pipeline(config), can_batches(sim.frames, 4096)):
            sink.write(step)
        if dropped:
            sink.write(StepOutput(events=make_events(EventKind.DROPPED, 1.0, 0, -1, dropped)))
    finally:
        sink.close()


@pytest.mark.parametrize("dropped", [0, 7])
def test_compare_judges_a_foreign_log_by_what_its_recording_lost(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys, dropped: int
) -> None:
    """Issue 28: "no frame lost FAIL 3.35e+05 frames" on a log of another run -- its frames
    were counted against plan level's simulated scenario. Now the check counts what the
    recording lost (its DROPPED events), and the checks that need the plan's truth are
    skipped with a note, since this log is not a run of that scenario."""
    monkeypatch.setenv("COLUMNS", "80")
    log = tmp_path / "foreign.mcap"
    record_foreign_run(log, dropped)
    main(["replay", str(log), "--compare", "--plan", "level", "-q"])
    out = capsys.readouterr().out
    table = rows(out)
    want = "FAIL 7 frames" if dropped else "PASS 0 frames"
    assert table["no frame lost"] == [want, want]
    assert table["bench estimator at standstill"] == ["SKIP", "SKIP"]  # needs the truth
    assert table["device availability near level"][0].split()[0] in ("PASS", "WARN", "FAIL")
    assert "foreign.mcap recorded a foreign board, not plan level's scenario" in out


def test_compare_replays_each_calibration_once(
    level_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """The replay the command does is the "after" side; "before" is replayed again only
    when its calibration differs (same calibration, same pipeline: the same results)."""
    from bench.acceptance import whatif

    calls: list[str] = []
    real = whatif.replay_side

    def counting(path: Path, config: object, label: str) -> whatif.Side:
        calls.append(label)
        return real(path, config, label)  # type: ignore[arg-type]

    monkeypatch.setattr(whatif, "replay_side", counting)
    assert main(["replay", str(level_run), "--compare", "--plan", "level", "-q"]) == 0
    assert calls == []
    tilted = tmp_path / "tilted.toml"
    tilted.write_text("[[channels]]\nangle_deg = 30.3\n[[channels]]\n[[channels]]\n")
    main(["replay", str(level_run), "--compare", "--config", str(tilted), "-q"])
    assert calls == ["before (recorded)"]
    capsys.readouterr()
