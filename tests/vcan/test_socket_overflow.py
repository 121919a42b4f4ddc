"""A full socket receive buffer: the kernel's drop count is read, reported and logged.

A reader that stops reading (here: a small buffer and a paused reader) makes the kernel
drop frames at its socket. Every frame sent is then either received or in that count.
"""

from __future__ import annotations

import re
import signal
import time

import pytest

from devices.bus import CanBusSource
from tests.vcan.support import (
    CHANNEL,
    cangen,
    log_info,
    need,
    read_log_frames,
    start_run,
    tool_missing,
    topic,
)

pytestmark = pytest.mark.vcan

SMALL = 4096
"""Bytes asked for: the kernel grants twice that, room for a handful of frames."""


def _drain(src: CanBusSource, quiet_s: float = 1.0) -> tuple[int, list]:
    """Read until nothing came for ``quiet_s``: (frames, notices)."""
    frames, notices = 0, []
    last = time.monotonic()
    while time.monotonic() - last < quiet_s:
        batch = src.read(0.1)
        if batch:
            frames += len(batch.frames)
            notices += batch.notices
            last = time.monotonic()
    return frames, notices


def test_a_burst_into_a_paused_reader_is_counted_by_the_kernel() -> None:
    need(tool_missing("cangen"))
    src = CanBusSource("socketcan", CHANNEL, rcvbuf=SMALL)
    try:
        granted = src.bus.rcvbuf_bytes  # type: ignore[union-attr]
        assert granted < 64 * 1024  # small enough for a burst of 500 frames to overflow
        frames, notices = _drain(src, 0.2)  # nothing on the bus yet; the buffer notice
        assert frames == 0
        assert [n.kind for n in notices] == ["info"]
        assert f"socket receive buffer {granted} bytes" in notices[0].detail
        # the reader pauses while 500 frames arrive, then reads on
        assert cangen("-I", "123", "-L", "8", "-D", "i", "-g", "0", "-n", "500").wait(60) == 0
        got, notices = _drain(src)
        assert 0 < got < 500
        # the count comes with the first frame queued after the drops
        assert cangen("-I", "124", "-L", "8", "-g", "0", "-n", "1").wait(60) == 0
        tail, more = _drain(src)
        notices += more
        assert tail == 1
        dropped = [n for n in notices if n.kind == "overflow"]
        assert sum(n.count for n in dropped) == src.kernel_drops == 500 - got
        assert all("dropped" in n.detail and "receive buffer full" in n.detail for n in dropped)
    finally:
        src.close()


def test_the_bench_reports_kernel_drops_in_health_and_events(tmp_path) -> None:
    need(tool_missing("cangen"))
    # python-can's CAN_CONFIG passes rcvbuf on to the socketcan bus, as ~/.canrc would
    run, _csv, mcap = start_run(tmp_path, "paused", env={"CAN_CONFIG": f'{{"rcvbuf": {SMALL}}}'})
    run.signal(signal.SIGSTOP)  # a bench that stopped reading
    try:
        assert cangen("-I", "123", "-L", "8", "-D", "i", "-g", "0", "-n", "300").wait(60) == 0
    finally:
        run.signal(signal.SIGCONT)
    time.sleep(1.0)
    # slow traffic after the burst: it carries the count to the bench
    assert cangen("-I", "124", "-L", "8", "-g", "20", "-n", "100").wait(60) == 0
    # the small buffer may overflow again under the slow tail reader; once it has drained,
    # one more frame brings the final count
    run.wait_settled(quiet_s=2.0)
    assert cangen("-I", "125", "-L", "8", "-n", "1").wait(60) == 0
    run.wait_received(401)  # received + dropped by the kernel
    assert run.stop() == 0, run.text()
    logged = len(read_log_frames(mcap))
    drops = 401 - logged
    assert drops > 0
    notices = [n for n in topic(mcap, "/source/notices") if n["kind"] == "overflow"]
    assert sum(n["count"] for n in notices) == drops
    health = topic(mcap, "/bench/health")
    assert health[-1]["socket_drops"] == drops
    assert [h["socket_drops"] for h in health] == sorted(h["socket_drops"] for h in health)
    info = log_info(mcap)
    assert info["events"]["SOCKET_OVERFLOW"] == len(notices)
    assert info["notices"]["overflow"] == len(notices)
    assert re.search(rf"dropped by the kernel\s+{drops}\n", run.text())  # closing summary
    assert re.search(rf" kdrop {drops}\b", run.text())  # and its last status line
