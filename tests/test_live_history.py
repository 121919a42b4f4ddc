"""The UI's result history: a snapshot holds the newest rows, oldest first, across ring wraps."""

from __future__ import annotations

import numpy as np
import pytest

import bench.live.runner as live
from bench.config import Config
from bench.pipeline.steps import StepOutput
from bench.records.results import RESULT_DTYPE
from devices.base import LiveSource, SourceBatch


class _Silent(LiveSource):
    def read(self, timeout: float) -> SourceBatch:
        return SourceBatch()

    def close(self) -> None:
        pass


def _rows(first: int, k: int) -> np.ndarray:
    out = np.zeros(k, dtype=RESULT_DTYPE)
    out["n"] = np.arange(first, first + k)
    return out


@pytest.mark.parametrize("sizes", [[3, 4, 2, 7, 1, 9, 5], [10, 10, 10], [25], [1] * 23])
def test_snapshot_rows_are_the_newest_in_order(
    monkeypatch: pytest.MonkeyPatch, sizes: list[int]
) -> None:
    monkeypatch.setattr(live, "HISTORY", 10)
    runner = live.LiveRunner(_Silent(), Config())
    sent = 0
    for k in sizes:
        runner._deliver(StepOutput(results=_rows(sent, k)))
        sent += k
        held = min(sent, 10)
        for last in (0, 1, 3, 9, 10, 50):
            got = runner.snapshot(last=last).results["n"].tolist()
            want = list(range(sent - min(last, held), sent))
            assert got == want, (sizes, sent, last)
