"""Pictures of the main screen (pytest-textual-snapshot) in the valid, degraded and invalid states.

Each picture comes from a fixed Snapshot: known frames run through a real LiveRunner to the
end, with everything the clock would change (wall time, latency, recording figures) frozen.
The estimator's columns are pinned too, so these pictures test the screen, not the estimator
(which has its own tests). Regenerate after an intended change with
``pytest tests/test_tui_snapshots.py --snapshot-update`` and look at the SVGs.
"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from bench.live.session import Session
from bench.live.view import Snapshot
from bench.records.events import EventKind
from bench.sinks.base import RecordingStatus
from bench.tui.app import BenchApp
from protocol.layout import STATUS_SELFTEST
from tests.test_tui_support import T0, make_frames, screen_text, settled_snapshot

SIZE = (100, 30)
WIDE = (140, 42)


def fixed(tail: np.ndarray, *, excluded: int = 0, signed: float = 20.0) -> Snapshot:
    """300 clean instants (20 permil) followed by ``tail``; estimator columns pinned."""
    snap = settled_snapshot(np.concatenate([make_frames(300), tail]), estimator=False)
    res = snap.results
    res["gradient_signed"] = signed
    res["gradient_ls"] = abs(signed)
    res["a_ref"] = 0.0
    res["residual"] = 0.0002
    res["degraded"] = False
    res["excluded"] = 0
    res["gradient_sigma"] = 0.12
    res["odometer_suspect"] = False
    res["coasting"] = False
    if excluded:
        bad = res["n"] >= 300
        res["degraded"][bad] = True
        res["excluded"][bad] = excluded
        res["residual"][bad] = 0.0007
    snap.source = "virtual board demo.toml"
    snap.recording = RecordingStatus(
        path="logs/20231114T221320Z-emu-demo.mcap",
        frames=snap.frames_received,
        bytes=48_213,
        duration_s=2.0,
    )
    snap.extra["frames_sent"] = snap.frames_received
    assert snap.events and snap.events[0][0] >= T0  # times come from the frames, not the clock
    return snap


def valid() -> Snapshot:
    return fixed(make_frames(100, start=300))


def degraded() -> Snapshot:
    # ch3 off by 0.15 mm/s^2: g12 and g13 still agree, g23 does not -> v1 fails, 2/3 votes
    return fixed(make_frames(100, start=300, perturb_mps2=(0.0, 0.0, 0.00015)))


def invalid() -> Snapshot:
    # ch2 flags SELFTEST: g12 and g23 cannot be computed -> all votes fail; ours excludes ch2
    return fixed(make_frames(100, start=300, status=(0, STATUS_SELFTEST, 0)), excluded=2)


def troubled() -> Snapshot:
    """Valid, with what the health line must not hide at 100x30 (issue 28): the kernel
    dropped 12 frames, the source disconnected once; and two operator marks."""
    snap = valid()
    snap.stats.socket_drops = 12
    snap.stats.events[int(EventKind.DISCONNECT)] = 1
    t = snap.events[-1][0]
    snap.events += [
        (t + 0.5, int(EventKind.MARK), "MARK operator mark 1"),
        (t + 1.0, int(EventKind.MARK), "MARK operator mark 2"),
    ]
    return snap


@pytest.mark.parametrize("state", [valid, degraded, invalid], ids=lambda f: f.__name__)
def test_main_screen(snap_compare: object, state: object) -> None:
    snap = state()  # type: ignore[operator]
    app = BenchApp(Session(runner=None, fixed=snap), poll_hz=0)

    async def show(pilot: object) -> None:
        app.apply_snapshot(snap)
        await pilot.pause()  # type: ignore[attr-defined]

    assert snap_compare(app, terminal_size=SIZE, run_before=show)  # type: ignore[operator]


def test_states_are_what_the_pictures_claim() -> None:
    """Guard the fixtures: each picture really shows the state it is named after."""
    for make, votes in (
        (valid, [True, True, True]),
        (degraded, [False, True, True]),
        (invalid, [False, False, False]),
    ):
        row = make().results[-1]
        assert row["votes"].tolist() == votes, make.__name__


@pytest.mark.parametrize(
    ("keys", "size"),
    [(("question_mark",), SIZE), (("p",), SIZE), ((), (90, 28))],
    ids=["help", "paused", "too-small"],
)
def test_screen_states(snap_compare: object, keys: tuple[str, ...], size: tuple[int, int]) -> None:
    """The help over the screen, the paused title, the too-small notice."""
    snap = valid()
    app = BenchApp(Session(runner=None, fixed=snap), poll_hz=0)

    async def show(pilot: object) -> None:
        app.apply_snapshot(snap)
        await pilot.pause()  # type: ignore[attr-defined]

    assert snap_compare(app, terminal_size=size, press=keys, run_before=show)  # type: ignore[operator]


@pytest.mark.parametrize("size", [SIZE, WIDE], ids=lambda s: f"{s[0]}x{s[1]}")
def test_every_panel_at_size(snap_compare: object, size: tuple[int, int]) -> None:
    """The smallest screen the bench supports and the one of the README's picture."""
    snap = troubled()
    app = BenchApp(Session(runner=None, fixed=snap), poll_hz=0)

    async def show(pilot: object) -> None:
        app.apply_snapshot(snap)
        await pilot.pause()  # type: ignore[attr-defined]

    assert snap_compare(app, terminal_size=size, run_before=show)  # type: ignore[operator]


@pytest.mark.parametrize("size", [SIZE, WIDE], ids=lambda s: f"{s[0]}x{s[1]}")
def test_nothing_that_matters_is_cut_at_size(size: tuple[int, int]) -> None:
    """At 100x30 the marks list had no row and the bus line was cut at "parse 0..." so that
    disc and kdrop were hidden (issue 28). In the order that matters: the per-pair values,
    the estimator, the health counters, the events, the marks."""
    snap = troubled()
    app = BenchApp(Session(runner=None, fixed=snap), poll_hz=0)

    async def run() -> str:
        async with app.run_test(size=size) as pilot:
            app.apply_snapshot(snap)
            await pilot.pause()
            return screen_text(app)

    text = asyncio.run(run())
    for pair in ("g12     19.985", "g23     20.000", "g13     19.993"):
        assert pair in text
    assert "±0.12 σ" in text and "ours: LS 20.00‰" in text
    assert "kdrop 12" in text and "disc 1" in text and "parse 0" in text and "CRC 0" in text
    assert "samples 400 lost 0" in text
    assert "BOARD_STATE value 1" in text
    assert "operator mark 1" in text and "operator mark 2" in text
    assert "logs/20231114T221320Z-emu-demo.mcap" in text and "1320 frames" in text
    assert "…" not in text.replace("finishing the log…", "")  # nothing cut short
