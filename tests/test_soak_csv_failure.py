"""The soak's promise with a secondary sink failing mid-run (issue 16 "done when").

The soak's board (1 kHz x 3 channels, benchmarks/common.py) with the soak's schedule of
every fault kind, through the real ``bench run --emulate ... --csv ... --mcap ...``; the
CSV's file takes some seconds of rows and then refuses every write with ENOSPC (a full disk,
without root or a tmpfs). Frames sent (the scenario's frames, from the emulator) =
received (the run's summary) = logged (read back from the MCAP); the failure is loud: an
OUTPUT_ERROR event in the log, the status line's flag, an error line and exit code 1.
The 10-minute version: ``python -m benchmarks.soak --no-tui --csv-fails-after-bytes N``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from bench.cli import main
from benchmarks.common import board_scenario
from benchmarks.soak import failing_csv_opener, fault_schedule
from tests.helpers import scenario_toml

SECONDS = 8.0
FAIL_AFTER_BYTES = 300_000  # ~2 s of 1 kHz result rows


def test_soak_board_with_the_csv_failing_mid_run(
    tmp_path: Path, monkeypatch: Any, capsys: Any
) -> None:
    from bench.sinks import tables as table_sinks
    from devices.emulator import load_scenario, simulate

    faults = fault_schedule(SECONDS, cycles=1)
    assert len({f["kind"] for f in faults}) >= 13  # every fault kind is in the run
    sc = tmp_path / "soak_board.toml"
    sc.write_text(scenario_toml(board_scenario(SECONDS, faults=faults)))
    sent = len(simulate(load_scenario(sc)).frames)

    monkeypatch.setattr(table_sinks, "open_stream", failing_csv_opener(FAIL_AFTER_BYTES))
    out, log = tmp_path / "live.csv", tmp_path / "run.mcap"
    code = main(["run", "--emulate", str(sc), "--csv", str(out), "--mcap", str(log)])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert code == 1, err[-2000:]
    received = int(re.search(r"^frames\s+(\d+)\s*$", err, re.M).group(1))  # type: ignore[union-attr]
    monkeypatch.undo()
    assert main(["log", "info", str(log), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert sent == received == info["frames"], (sent, received, info["frames"])
    assert not info["truncated"]

    # failed mid-run, not at the start: rows reached the file, then rows were lost; the
    # file is removed (never half a file under its name), the MCAP holds every row
    written = re.search(r"not written \((\d+) result rows had been written", err)
    assert written and int(written.group(1)) > 100, err[-2000:]
    assert not out.exists()
    assert f"bench: error: {out}: cannot write the CSV: No space left on device" in err
    assert "CSV FAILED" in err
    from mcap.reader import make_reader

    with log.open("rb") as f:
        events = [
            json.loads(m.data)["message"]
            for _s, _c, m in make_reader(f).iter_messages(topics=["/bench/events"])
        ]
    assert any(e.startswith("OUTPUT_ERROR No space left on device") for e in events)
