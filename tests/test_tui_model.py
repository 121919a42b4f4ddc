"""The TUI's model panel and the plot's lagged line (issue 26, `--lag`): shown only when the
run has the live model; each estimate with its sigma, in the units the panel states (values
written by hand into the view)."""

from __future__ import annotations

import asyncio

import numpy as np

from bench.live.session import Session
from bench.live.view import ModelView
from bench.records.model import MODEL_DTYPE
from bench.tui.app import BenchApp
from bench.tui.panels.model import model_lines
from tests.test_tui_snapshots import valid
from tests.test_tui_support import screen_text


def _view(lag_s: float = 2.0) -> ModelView:
    row = np.zeros(1, dtype=MODEL_DTYPE)[0]
    row["wheel_error"], row["wheel_error_sigma"] = 0.0123, 0.0005
    row["compliance"], row["compliance_sigma"] = 0.051, 0.012
    row["bias"] = (9.80665e-3, -2 * 9.80665e-3, 0.0)
    row["bias_sigma"] = (0.5 * 9.80665e-3,) * 3
    lagged = np.array([[10.0, 11.5, 0.1], [10.02, 12.25, 0.04]])
    return ModelView(lag_s, row, lagged, 2, 0, 0, 0, True)


def test_the_model_panel_shows_each_estimate_with_its_sigma() -> None:
    lines = model_lines(_view()).plain.splitlines()
    assert lines[0].split() == ["wheel", "+1.23", "±", "0.05", "%"]
    assert lines[1].split() == ["pitch", "+0.051", "±", "0.012", "°/(m/s²)"]
    assert lines[2].split() == ["bias", "+1.00", "-2.00", "+0.00", "mg"]
    assert lines[3].split() == ["±", "0.50", "0.50", "0.50", "mg"]
    assert lines[4].split()[:5] == ["lag", "2s", "+12.25", "±", "0.04"]


def test_the_panel_counts_what_a_full_queue_dropped_in_bold_red() -> None:
    full = ModelView(2.0, None, np.zeros((0, 3)), 0, 40, 3, 120, True)
    text = model_lines(full)
    last = text.plain.splitlines()[-1]
    assert last.endswith("q 40 drop 3")
    assert any(str(span.style) == "bold red" for span in text.spans)


def test_the_screen_shows_the_model_only_when_the_run_has_it() -> None:
    async def shown(model: ModelView | None) -> str:
        snap = valid()
        snap.model = model
        app = BenchApp(Session(runner=None, fixed=snap), poll_hz=0)  # type: ignore[arg-type]
        async with app.run_test(size=(140, 40)) as pilot:
            app.apply_snapshot(snap)
            await pilot.pause()
            return screen_text(app)

    without = asyncio.run(shown(None))
    assert "Model" not in without and "lag 2 s" not in without
    with_model = asyncio.run(shown(_view()))
    assert "Model" in with_model and "+1.23 ± 0.05 %" in with_model
    assert "lag 2 s" in with_model  # the plot's legend names the lagged line
