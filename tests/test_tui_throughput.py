"""The TUI never costs a frame: a short run of benchmarks/tui_1khz.py (the full run is 60 s).

The whole `bench tui --emulate` stack runs headless on a 1 kHz x 3 channel virtual board with
MCAP recording on; frames sent (the board's count) must equal frames received, processed and
logged (read back from the MCAP file the quit key finished), with no drops anywhere.
"""

from __future__ import annotations

from pathlib import Path

from benchmarks.tui_1khz import run


def test_tui_at_1khz_loses_no_frame(tmp_path: Path) -> None:
    result = run(5.0, workdir=str(tmp_path), marks=1)
    print(result.report())
    assert result.sent > 5 * 3000 * 0.9  # the board really ran at 1 kHz x 3 channels
    assert result.sent == result.received == result.processed == result.logged, result.report()
    assert result.runner_dropped == result.log_dropped == 0
    assert result.mcap_complete and result.marks_logged == 1
    assert result.snapshots >= 5  # the display was live all along
