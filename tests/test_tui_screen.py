"""The screen items of issue 18, headless (App.run_test + Pilot) on fixed snapshots and
known events: plot colours and drawing order, round ticks, merged event rows with their
latest time, marks apart, the kind filter, the too-small notice, help and Escape, the
footer, PAUSED, and the palette's screenshot landing under logs/."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

import numpy as np
import pytest

from bench.live.session import Session
from bench.records.events import EventKind
from bench.tui.app import BenchApp
from bench.tui.help import HelpScreen
from bench.tui.panels.events import EventsPanel, MarksPanel, merge_events, stamp
from bench.tui.panels.plot import TRACES, PlotSeries, legend_markup, render_plot, y_ticks
from tests.test_tui_app import wait_for
from tests.test_tui_snapshots import valid
from tests.test_tui_support import T0, screen_text

SIZE = (100, 30)


def fixed_app(**kwargs: object) -> tuple[BenchApp, object]:
    snap = valid()
    return BenchApp(Session(runner=None, fixed=snap), poll_hz=0, **kwargs), snap  # type: ignore[arg-type]


# -- plot --------------------------------------------------------------------------------------
def test_five_traces_five_colours_legend_alike_final_drawn_last() -> None:
    colours = [c for _, _, c in TRACES]
    assert len(set(colours)) == 5
    assert TRACES[-1][0] == "gradient"  # drawn last: on top
    for _, label, colour in TRACES:
        assert f"[{colour}]{label}[/]" in legend_markup()
    # every trace on the same values: the cells show the final gradient's colour only
    x = np.linspace(-10, 0, 200)
    y = {key: np.full(200, 5.0) for key, _, _ in TRACES}
    text = render_plot(
        __import__("textual_plotext.plot").plot.Plot(), PlotSeries(10, x, y, 10), 60, 12
    )
    styles = {str(span.style) for span in text.spans}
    assert styles == {dict((k, c) for k, _, c in TRACES)["gradient"]}


@pytest.mark.parametrize(
    ("lo", "hi", "rows"),
    [(-0.3, 62.8, 14), (0.2, 40.4, 10), (19.21, 20.83, 12), (-3.7, 1.1, 8), (-250.0, 900.0, 20)],
)
def test_y_ticks_are_round_and_include_zero(lo: float, hi: float, rows: int) -> None:
    ticks, labels = y_ticks(lo, hi, rows)
    assert len(ticks) >= 2
    steps = np.diff(ticks)
    assert np.allclose(steps, steps[0])
    mantissa = steps[0] / 10 ** np.floor(np.log10(steps[0]))
    assert any(abs(mantissa - m) < 1e-9 for m in (1, 2, 5))  # a 1-2-5 step
    assert all(lo <= t <= hi for t in ticks)
    for t, label in zip(ticks, labels, strict=True):
        assert abs(float(label) - t) < 1e-9  # the label is the tick's exact value
    if lo < 0 < hi:
        assert "0" in labels  # not 0.2 or -0.0
    assert not any(label.startswith("-0") and float(label) == 0 for label in labels)


def test_plot_labels_on_screen_are_round() -> None:
    app, snap = fixed_app()

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            app.apply_snapshot(snap)  # type: ignore[arg-type]
            await pilot.pause()
            lines = screen_text(app).splitlines()
            top = next(i for i, ln in enumerate(lines) if "Gradient" in ln)
            labelled = [
                (i, float(m.group(1)))
                for i, ln in enumerate(lines[top + 1 : top + 20], start=top + 1)
                if (m := re.match(r"│(-?\d+\.?\d*) ", ln))
            ]
            assert len(labelled) >= 2, "no y labels"
            rows = [i for i, _ in labelled]
            values = [v for _, v in labelled]
            assert len(set(np.round(np.diff(values), 9))) == 1  # evenly spaced values
            assert min(np.diff(rows)) >= 2  # never on adjacent rows

    asyncio.run(run())


# -- events --------------------------------------------------------------------------------------
def test_a_merged_row_shows_its_latest_time_and_sample_range() -> None:
    fail = int(EventKind.VOTE_FAIL)
    fresh = [(T0 + 0.005 * k, fail, f"VOTE_FAIL sample {100 + k} failed v1") for k in range(31)]
    added, changed = merge_events([], fresh)
    assert len(added) == 1 and not changed
    row = added[0]
    assert (row.count, row.first_n, row.last_n) == (31, 100, 130)
    assert row.t == T0 + 0.005 * 30  # the latest occurrence, not the first
    assert row.when().plain == stamp(T0 + 0.15)
    # more of the same in a later poll: the row on screen is updated, time included
    more, changed = merge_events(added, [(T0 + 1.0, fail, "VOTE_FAIL sample 131 failed v1")])
    assert not more and changed == [row] and row.t == T0 + 1.0 and row.count == 32


def test_marks_stay_in_their_own_list_under_a_flood_of_vote_failures() -> None:
    app, snap = fixed_app()
    fail, mark = int(EventKind.VOTE_FAIL), int(EventKind.MARK)
    events = [(T0 + 1.0, mark, "MARK operator mark 1")]
    # 600 distinct failures (different votes, so no merging): more than the panel keeps
    events += [
        (T0 + 1.0 + k / 200, fail, f"VOTE_FAIL sample {k} failed v{1 + k % 3} x{k}")
        for k in range(600)
    ]

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            app.apply_snapshot(snap)  # type: ignore[arg-type]
            await pilot.pause()
            app.query_one(EventsPanel).show([*snap.events, *events])  # type: ignore[attr-defined]
            await pilot.pause()
            marks = app.query_one(MarksPanel).texts()
            assert marks == [f"{stamp(T0 + 1.0)[:8]} operator mark 1"]
            assert "operator mark 1" in screen_text(app)  # visible, not scrolled away
            assert not any("mark" in e for e in app.query_one(EventsPanel).texts())

    asyncio.run(run())


def test_filter_by_kind_cycles_through_the_kinds_seen() -> None:
    app, snap = fixed_app()
    gap, crc = int(EventKind.GAP), int(EventKind.CRC_ERROR)
    events = [
        (T0 + 1.0, gap, "GAP ch3 sample 10"),
        (T0 + 1.1, crc, "CRC_ERROR ch1 id 0x101"),
        (T0 + 1.2, gap, "GAP ch2 sample 12"),
    ]

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            app.apply_snapshot(snap)  # type: ignore[arg-type]
            await pilot.pause()
            panel = app.query_one(EventsPanel)
            panel.show([*snap.events, *events])  # type: ignore[attr-defined]
            await pilot.pause()
            everything = panel.texts()
            kinds = sorted(panel.kinds_seen)
            for kind in kinds:  # in EventKind order, then back to all
                await pilot.press("f")
                assert panel.only == kind
                shown = panel.texts()
                assert shown and all(EventKind(kind).name in s for s in shown)
            await pilot.press("f")
            assert panel.only is None and panel.texts() == everything
            assert len(everything) == 4  # BOARD_STATE from the run, plus the three above

    asyncio.run(run())


# -- screen-wide ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("size", "small"), [((99, 30), True), ((100, 29), True), ((100, 30), False)]
)
def test_below_100x30_the_screen_says_it_is_too_small(size: tuple[int, int], small: bool) -> None:
    app, snap = fixed_app()

    async def run() -> None:
        async with app.run_test(size=size) as pilot:
            app.apply_snapshot(snap)  # type: ignore[arg-type]
            await pilot.pause()
            text = screen_text(app)
            assert ("too small" in text) is small
            assert ("Per pair" in text) is not small  # the panels give way, not cropped

    asyncio.run(run())


def test_help_opens_with_question_mark_and_escape_closes_it() -> None:
    app, snap = fixed_app()

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            app.apply_snapshot(snap)  # type: ignore[arg-type]
            await pilot.press("question_mark")
            await wait_for(pilot, lambda: isinstance(app.screen, HelpScreen))
            text = screen_text(app)
            for key in ("plot window", "operator mark", "vote tolerance"):
                assert key in text
            await pilot.press("escape")
            await wait_for(pilot, lambda: not isinstance(app.screen, HelpScreen))
            await pilot.press("ctrl+p")
            await pilot.pause()
            await pilot.press("escape")  # the palette closes on Escape too
            await pilot.pause()
            assert "Per pair" in screen_text(app)

    asyncio.run(run())


def test_footer_shows_w_and_help_and_title_says_paused() -> None:
    app, snap = fixed_app()

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            app.apply_snapshot(snap)  # type: ignore[arg-type]
            # the footer is drawn after the first refresh, which a loaded machine delays
            await wait_for(pilot, lambda: "Quit" in screen_text(app).splitlines()[-1])
            footer = screen_text(app).splitlines()[-1]
            for key in ("w Window", "f Filter", "? Help", "p Pause display"):
                assert key in footer
            assert "PAUSED" not in screen_text(app).splitlines()[0]
            await pilot.press("p")
            await wait_for(pilot, lambda: " PAUSED " in screen_text(app).splitlines()[0])
            await pilot.press("p")
            await pilot.pause()
            assert "PAUSED" not in screen_text(app).splitlines()[0]

    asyncio.run(run())


def test_screenshot_goes_under_logs_without_a_downloads_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))  # no ~/Downloads
    monkeypatch.setenv("XDG_DOWNLOAD_DIR", str(home / "Downloads"))
    monkeypatch.chdir(tmp_path)
    app, snap = fixed_app()

    async def run() -> None:
        async with app.run_test(size=SIZE) as pilot:
            app.apply_snapshot(snap)  # type: ignore[arg-type]
            titles = [c.title for c in app.get_system_commands(app.screen)]
            assert titles.count("Screenshot") == 1
            command = next(
                c for c in app.get_system_commands(app.screen) if c.title == "Screenshot"
            )
            command.callback()
            await wait_for(pilot, lambda: any((tmp_path / "logs").glob("*.svg")))

    asyncio.run(run())
    svg = next((tmp_path / "logs").glob("*.svg")).read_text()
    assert svg.startswith("<svg") and "Per pair" in svg.replace("&#160;", " ")
    assert not (home / "Downloads").exists()
