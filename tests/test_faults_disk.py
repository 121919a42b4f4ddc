"""The disk fills or the log path becomes unwritable mid-run.

Acquisition and the UI must survive (frames keep being received and fused, the screen keeps
updating) and the failure must be loud: on the screen while it lasts, and at the end of a
headless run as an error line and a non-zero exit code, never "log written".

* ``bench run`` as a subprocess under ``RLIMIT_FSIZE``: the kernel refuses writes past the
  limit (EFBIG), exactly as a full disk refuses them (ENOSPC), with no root or tmpfs needed.
* The TUI, headless, with the MCAP file's writes failing with ENOSPC from a chosen moment.
* The TUI, headless: the recording is stopped and restarted while the log folder is not
  usable (it became a file), then restarted again once it is.
"""

from __future__ import annotations

import asyncio
import errno
import re
import resource
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from tests.helpers import bench

LIMIT = 60_000

SCENARIO = """
description = "disk test: 200 Hz, level"
seed = 6
duration_s = 30.0
sample_rate_hz = 200
"""


@pytest.fixture
def scenario(tmp_path: Path) -> Path:
    p = tmp_path / "disk_test.toml"
    p.write_text(SCENARIO, encoding="utf-8")
    return p


def limit_file_size() -> None:  # runs in the child between fork and exec
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


@pytest.fixture(scope="module")
def full_disk_run(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[subprocess.CompletedProcess, Path]:
    d = tmp_path_factory.mktemp("fulldisk")
    sc = d / "disk_test.toml"
    sc.write_text(SCENARIO, encoding="utf-8")
    mcap = d / "run.mcap"
    args = ["run", "--emulate", str(sc), "--mcap", str(mcap), "--duration", "5"]
    proc = bench(*args, preexec_fn=limit_file_size)
    return proc, mcap


def _summary_frames(stderr: str) -> int:
    m = re.search(r"^frames\s+(\d+)\s*$", stderr, re.M)
    assert m, stderr
    return int(m.group(1))


def test_full_disk_mid_run_acquisition_goes_on(full_disk_run: Any) -> None:
    proc, mcap = full_disk_run
    assert "Traceback" not in proc.stderr
    assert mcap.stat().st_size == LIMIT  # the log really hit the wall
    # 3 s of a 200 Hz board is ~2000 frames; the log stopped far earlier than that
    assert _summary_frames(proc.stderr) > 1500, proc.stderr
    assert "File too large" in proc.stderr  # said when it happened


def test_full_disk_mid_run_is_an_error_at_the_end(full_disk_run: Any) -> None:
    proc, _ = full_disk_run
    tail = proc.stderr.strip().splitlines()[-3:]
    assert proc.returncode != 0, f"exit 0 after the log failed; last lines: {tail}"
    assert not any("log written" in line for line in tail), tail
    assert any(line.startswith("bench: error:") and "File too large" in line for line in tail)


def test_log_cut_by_full_disk_is_readable(full_disk_run: Any) -> None:
    _, mcap = full_disk_run
    proc = bench("log", "info", str(mcap), "--json")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr
    import json

    info = json.loads(proc.stdout)
    assert info["truncated"] and "warning" in proc.stderr
    from bench.mcaplog.reader import McapLog
    from bench.mcaplog.schemas import FRAME_TOPIC

    with McapLog(mcap) as log:
        assert log.message_counts()[FRAME_TOPIC] > 100  # every complete chunk is kept


# --------------------------------------------------------------------------- TUI
class _FailingFile:
    """A file object whose writes fail with ENOSPC once ``full`` is set."""

    full = threading.Event()

    def __init__(self, f: Any) -> None:
        self._f = f

    def write(self, data: Any) -> int:
        if self.full.is_set():
            raise OSError(errno.ENOSPC, "No space left on device")
        return self._f.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


def _session(tmp_path: Path, channel: str) -> tuple[Any, Any, Any]:
    import can

    from bench.config import Config
    from bench.live.session import live_session
    from bench.live.setup import LiveSetup, start_recording
    from devices.bus import CanBusSource
    from devices.emulator import scenario_from_dict, start_virtual_board

    sc = scenario_from_dict({"duration_s": 60.0, "sample_rate_hz": 200, "seed": 9})
    bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    source = CanBusSource(bus=bus, owns_bus=True)
    setup = LiveSetup(source, "virtual board (test)", "disk-test")
    config = Config(sample_rate_hz=200)
    first = start_recording(tmp_path / "logs" / "first.mcap", setup, config)
    session = live_session(setup, config, first, tmp_path / "logs")
    session.start()
    setup.emulator = start_virtual_board(sc, channel)
    return session, setup, first


def _panel_text(app: Any, selector: str) -> str:
    """What one panel shows, its lines joined without spaces (long lines wrap anywhere)."""
    from textual.geometry import Region

    widget = app.query_one(selector)
    strips = widget.render_lines(Region(0, 0, widget.size.width, widget.size.height))
    text = "".join("".join(seg.text for seg in strip) for strip in strips)
    return re.sub(r"[\s\u2500-\u257f]", "", text)  # no spaces, no box-drawing border


async def _until(cond: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return
        await asyncio.sleep(0.05)
    pytest.fail(f"timed out waiting for {what}")


def test_tui_survives_disk_full_and_shows_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import builtins

    import bench.mcaplog.file as writer
    from bench.tui.app import BenchApp

    real_open = builtins.open
    _FailingFile.full.clear()
    monkeypatch.setattr(
        writer, "open", lambda *a, **k: _FailingFile(real_open(*a, **k)), raising=False
    )
    monkeypatch.setenv("BENCH_LOG_WRITER", "thread")  # the failing file is in this process
    session, _, first = _session(tmp_path, f"disk-tui-{id(tmp_path)}")
    app = BenchApp(session, poll_hz=10.0)

    async def scenario() -> None:
        async with app.run_test(size=(200, 60)) as pilot:
            runner = session.runner
            await _until(lambda: runner.frames_received > 300, 10, "frames before the fault")
            _FailingFile.full.set()
            await _until(lambda: first.error is not None, 10, "the sink to notice the full disk")
            seen, shown = runner.frames_received, app.snapshots_applied
            await _until(lambda: runner.frames_received > seen + 600, 10, "acquisition after it")
            await _until(lambda: app.snapshots_applied > shown + 3, 10, "the screen updating")
            await pilot.pause()
            # the reason first, above the long path, whatever the panel's size crops
            assert "LOGFAILED:Nospaceleftondevice" in _panel_text(app, "#recording")
            header = _panel_text(app, "#status-bar")
            assert "LOGFAILED" in header and "REC" not in header.replace("LOGFAILED", "")
            assert runner.error is None
            await pilot.press("q")
            await _until(lambda: not app.is_running, 15, "the app to quit")

    try:
        asyncio.run(scenario())
    finally:
        _FailingFile.full.clear()
        session.stop()
    assert "No space left on device" in (first.error or "")
    assert session.runner.frames_dropped == 0


def test_tui_log_folder_unusable_then_usable_again(tmp_path: Path) -> None:
    from bench.tui.app import BenchApp

    session, _, _ = _session(tmp_path, f"disk-folder-{id(tmp_path)}")
    app = BenchApp(session, poll_hz=10.0)
    logs = tmp_path / "logs"
    parked = tmp_path / "logs.parked"

    async def scenario() -> None:
        async with app.run_test(size=(200, 60)) as pilot:
            runner = session.runner
            await _until(lambda: runner.frames_received > 200, 10, "frames")
            await pilot.press("r")  # stop recording
            await _until(lambda: not session.recorder.active, 5, "recording to stop")
            logs.rename(parked)
            logs.write_text("not a folder any more")
            await pilot.press("r")  # cannot start: the folder is a file now
            await pilot.pause()
            assert not session.recorder.active
            seen = runner.frames_received
            await _until(lambda: runner.frames_received > seen + 300, 10, "acquisition going on")
            logs.unlink()
            parked.rename(logs)
            await pilot.press("r")  # works again
            await _until(lambda: session.recorder.active, 5, "recording to restart")
            await pilot.press("q")
            await _until(lambda: not app.is_running, 15, "the app to quit")

    try:
        asyncio.run(scenario())
    finally:
        session.stop()
    assert session.runner.error is None
    files = sorted(p for p in logs.glob("*.mcap"))
    assert len(files) == 2  # the first recording and the one after the folder came back
    from bench.mcaplog.reader import McapLog

    for f in files:
        with McapLog(f) as log:
            assert log.complete, f
