"""Toggling the recording (r, r) under a live run at 1 kHz x 3 channels with the MCAP writer
process: the stop finishes its file, the start opens another and the run loses nothing
(benchmarks/rec_toggle.py runs the same and measures the latency around the toggles).

That the processing thread does not wait for the new file to open -- which once delivered
the results of a second hundreds of ms late -- is held without a clock by
tests/test_tui_session.py (the open is held back until the writes have gone through).
"""

from __future__ import annotations

import math

from benchmarks.rec_toggle import run


def test_recording_toggled_under_a_live_run_gives_two_files_and_drops_nothing() -> None:
    r = run(before_s=2.0, after_s=3.0, toggles=1)
    assert not r.errors, r.report()
    assert r.files == 2 and r.dropped == 0, r.report()
    # results kept coming after the new file was opened (their latency has a p99)
    assert len(r.after) == 1 and not math.isnan(r.after[0][1]), r.report()
