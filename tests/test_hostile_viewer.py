"""A Foxglove viewer that subscribes and never reads cannot hold a run (issue 27).

Before: such a client kept `bench run --duration 10` alive for minutes, and SIGTERM did not
end it; any viewer that could reach the port could hold a run. The viewer here is
:class:`tests.foxglove_client.StalledClient` (a raw socket on 127.0.0.1 with a 4 KiB
receive buffer that reads nothing after it subscribed); the run must end at its
``--duration`` and on SIGTERM, with a finished MCAP log whose length is the run's. The
limits below are hang guards, never speed bounds.
"""

from __future__ import annotations

import contextlib
import re
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.mcaplog.info import log_info
from tests.foxglove_client import SUBPROTOCOLS, StalledClient
from tests.test_hostile_records import bench

GUARD_S = 180.0


class Lines:
    """A stream's lines as they come (a thread reads it; the test waits for one)."""

    def __init__(self, stream) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.append(line)

    def wait(self, pattern: str, proc: subprocess.Popen[str], after: int = 0) -> re.Match[str]:
        deadline = time.monotonic() + GUARD_S
        while time.monotonic() < deadline:
            for line in self.lines[after:]:
                if m := re.search(pattern, line):
                    return m
            assert proc.poll() is None or self._thread.is_alive(), "".join(self.lines)
            time.sleep(0.05)
        raise AssertionError(f"no line matching {pattern!r}: {''.join(self.lines)}")

    def text(self) -> str:
        self._thread.join(GUARD_S)
        return "".join(self.lines)


def _wait_for_bytes(path: Path, proc: subprocess.Popen[str], size: int) -> None:
    """Until the live log holds ``size`` bytes (a hang guard, not a speed bound)."""
    deadline = time.monotonic() + GUARD_S
    while not (path.exists() and path.stat().st_size >= size):
        assert proc.poll() is None, "the run ended early"
        assert time.monotonic() < deadline, f"{path} never reached {size} bytes"
        time.sleep(0.05)


@contextlib.contextmanager
def _stalled_run(
    tmp_path: Path, duration: str, subprotocol: str = SUBPROTOCOLS[0]
) -> Iterator[tuple[subprocess.Popen[str], Lines, Path, StalledClient]]:
    """``bench run --foxglove`` with a viewer connected that will read nothing; the run is
    killed and the viewer closed on the way out, whatever happened."""
    sc = tmp_path / "s.toml"
    sc.write_text("duration_s = 600.0\nseed = 2\n")
    log = tmp_path / "run.mcap"
    proc = bench(
        "run", "--emulate", str(sc), "--duration", duration, "--foxglove", "0",
        "--mcap", str(log), "--status-every", "0.2",
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    Lines(proc.stdout)  # drained, never read
    err = Lines(proc.stderr)
    viewer = None
    try:
        port = int(err.wait(r"Foxglove live stream on ws://127\.0\.0\.1:(\d+)", proc)[1])
        viewer = StalledClient(port, subprotocol)
        yield proc, err, log, viewer
    finally:
        if proc.poll() is None:
            proc.kill()
        if viewer is not None:
            viewer.close()


@pytest.mark.parametrize("subprotocol", SUBPROTOCOLS)
def test_a_viewer_that_never_reads_does_not_hold_the_run_past_its_duration(tmp_path, subprotocol):
    with _stalled_run(tmp_path, "4", subprotocol) as (proc, err, log, viewer):
        assert viewer.status == "HTTP/1.1 101 Switching Protocols"
        viewer.subscribe("/can/frames")  # and from now on reads nothing
        proc.wait(GUARD_S)  # without the fix: minutes, while the viewer stays connected
    assert proc.returncode == 0, err.text()
    info = log_info(log)
    assert info["complete"], info
    # the run's 4 s at most (under load the emulator's frames may cover less of them)
    assert 0 < info["duration_s"] <= 4.5, info["duration_s"]


def test_sigterm_ends_a_run_whose_viewer_never_reads(tmp_path):
    with _stalled_run(tmp_path, "600") as (proc, err, log, viewer):
        viewer.subscribe("/can/frames")
        _wait_for_bytes(log, proc, 100_000)  # the run goes on with the viewer stalled
        proc.send_signal(signal.SIGTERM)
        proc.wait(GUARD_S)  # without the fix SIGTERM did not end it
    assert proc.returncode == 0, err.text()
    info = log_info(log)
    assert info["complete"] and info["frames"] > 0, info


def test_a_run_says_what_a_stalled_viewer_cost(tmp_path):
    """The stalled viewer is let go (reset) while the run goes on, and the run's end says
    so in one warning; the log is whole."""
    with _stalled_run(tmp_path, "600") as (proc, err, log, viewer):
        viewer.subscribe("/can/frames")
        deadline = time.monotonic() + GUARD_S  # a hang guard: the cut comes after ~5 s
        while not viewer.was_let_go():
            assert proc.poll() is None and time.monotonic() < deadline, err.text()
            time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        proc.wait(GUARD_S)
    text = err.text()
    assert proc.returncode == 0, text
    warned = [ln for ln in text.splitlines() if "viewer disconnected" in ln]
    assert len(warned) == 1, text
    assert f"Foxglove live stream on ws://127.0.0.1:{viewer.port}: " in warned[0]
    assert "1 viewer disconnected (did not take what was sent within 5 s)" in warned[0]
    assert log_info(log)["complete"]


def test_the_viewer_warning_line():
    from bench.mcaplog.writer_process import viewer_warning

    assert viewer_warning({}) == ""
    assert viewer_warning({"messages_dropped": 0, "clients_cut": 0}) == ""
    assert viewer_warning({"messages_dropped": 12, "clients_cut": 0}) == (
        "12 messages dropped for viewers that fell behind (the run and its log are not affected)"
    )
    assert viewer_warning({"messages_dropped": 3, "clients_cut": 2}) == (
        "3 messages dropped for viewers that fell behind; 2 viewers disconnected (did not "
        "take what was sent within 5 s) (the run and its log are not affected)"
    )
    assert viewer_warning({"clients_refused": 1}) == (
        "1 connection refused (16 viewers were being served) (the run and its log are not affected)"
    )


def test_a_connection_that_never_sends_its_request_is_closed(monkeypatch):
    """A peer that connects and says nothing was kept forever, one task per connection."""
    import socket

    from bench.mcaplog import foxglove_front as front
    from bench.mcaplog.foxglove_ws import WsChannels

    monkeypatch.setattr(front, "HANDSHAKE_TIMEOUT_S", 1.0)
    ws = WsChannels(port=0)
    try:
        with socket.create_connection(("127.0.0.1", ws.port)) as quiet:
            quiet.settimeout(GUARD_S)  # a hang guard: the front closes it after 1 s
            assert quiet.recv(1024) == b""
    finally:
        ws.abort()


def test_connections_beyond_the_limit_are_refused_and_counted(monkeypatch):
    """Each stalled viewer may hold an outbox for a few seconds: their number is bounded."""
    import socket

    from bench.mcaplog import foxglove_front as front
    from bench.mcaplog.foxglove_ws import WsChannels

    monkeypatch.setattr(front, "MAX_CLIENTS", 2)
    ws = WsChannels(port=0)
    held = []
    try:
        held = [StalledClient(ws.port) for _ in range(2)]  # two viewers being served
        assert all(c.status == "HTTP/1.1 101 Switching Protocols" for c in held)
        with socket.create_connection(("127.0.0.1", ws.port)) as third:
            third.settimeout(GUARD_S)
            answer = b""
            while data := third.recv(1024):
                answer += data
        assert answer.startswith(b"HTTP/1.1 503 Service Unavailable\r\n"), answer
        assert ws.front.counts.clients_refused == 1
        held.pop().close()  # one goes: a new viewer is served again
        deadline = time.monotonic() + GUARD_S
        while True:  # until the front has seen the one that went (a hang guard)
            again = StalledClient(ws.port) if len(ws.front._tasks) < 2 else None
            if again is not None:
                held.append(again)
                break
            assert time.monotonic() < deadline
            time.sleep(0.05)
        assert again.status == "HTTP/1.1 101 Switching Protocols"
    finally:
        ws.abort()
        for c in held:
            c.close()


def _ws_frame(opcode: int, payload: bytes, fin: bool = True) -> bytes:
    """A server frame by RFC 6455 section 5.2 (unmasked), written here by hand."""
    b0 = (0x80 if fin else 0) | opcode
    n = len(payload)
    if n < 126:
        return bytes([b0, n]) + payload
    if n < 65536:
        return bytes([b0, 126]) + n.to_bytes(2, "big") + payload
    return bytes([b0, 127]) + n.to_bytes(8, "big") + payload


def test_split_frames_cuts_whole_frames_and_marks_only_message_data_droppable():
    from bench.mcaplog.foxglove_front import split_frames

    data = _ws_frame(0x2, b"\x01" + b"m" * 20)  # binary Message Data (opcode 0x01 byte)
    advert = _ws_frame(0x1, b'{"op": "advertise"}')  # text: never dropped
    time_ = _ws_frame(0x2, b"\x02" + b"t" * 8)  # binary Time: never dropped
    long = _ws_frame(0x2, b"\x01" + b"L" * 300)  # 16-bit length
    huge = _ws_frame(0x2, b"\x01" + b"H" * 70_000)  # 64-bit length
    part = _ws_frame(0x2, b"\x01" + b"p" * 10, fin=False)  # a fragment: never dropped
    ping = _ws_frame(0x9, b"")
    whole = data + advert + time_ + long + huge + part + ping
    buf = bytearray(whole + huge[:1000])  # and the start of one more
    got = split_frames(buf)
    assert [f for f, _ in got] == [data, advert, time_, long, huge, part, ping]
    assert [d for _, d in got] == [True, False, False, True, True, False, False]
    assert bytes(buf) == huge[:1000]  # the part frame stays for the next read
    buf += huge[1000:]
    assert split_frames(buf) == [(huge, True)] and not buf
    for cut in (1, 3, 9):  # a head cut inside its extended length: nothing yet
        buf = bytearray(huge[:cut])
        assert split_frames(buf) == [] and len(buf) == cut


def test_the_front_drops_and_counts_for_a_viewer_that_never_reads(monkeypatch):
    """Per client: a bounded outbox that drops Message Data (counted), a send timeout that
    lets a stalled client go (counted); a client that reads gets every message meanwhile."""
    from bench.mcaplog import foxglove_front as front
    from bench.mcaplog.foxglove_ws import WsChannels
    from tests.foxglove_client import Client

    monkeypatch.setattr(front, "OUTBOX_BYTES", 64 * 1024)
    monkeypatch.setattr(front, "SEND_TIMEOUT_S", 2.0)
    n, size = 4000, 1000  # 4 MB: far more than a stalled client's buffers hold
    ws = WsChannels(port=0)
    stalled = None
    try:
        sid = ws.add_schema("bench.Raw", "jsonschema", b'{"type": "object"}')
        cid = ws.add_channel("/can/frames", "json", sid)
        reader = Client(ws.port).start()
        stalled = StalledClient(ws.port).subscribe("/can/frames")
        time.sleep(0.5)  # the SDK takes the subscriptions (not a bound: a settle)
        payloads = [b'{"k": "' + f"{k:08d}".encode() + b"x" * (size - 17) + b'"}' for k in range(n)]
        deadline = time.monotonic() + GUARD_S
        step = 20  # 20 kB a time, well inside an outbox: paced by the reader that reads
        for k in range(0, n, step):
            ws.add_messages(
                cid, list(range(k + 1, k + step + 1)), payloads[k : k + step], [0] * step
            )
            while reader.received.counts().get("/can/frames", 0) < k + step:
                assert time.monotonic() < deadline, (k, ws.front.counts)
                time.sleep(0.005)
        while ws.front.counts.clients_cut < 1:
            assert time.monotonic() < deadline, ws.front.counts
            time.sleep(0.05)
        got = reader.wait_quiet(quiet_s=1.0).counts().get("/can/frames", 0)
        dropped = ws.front.counts.messages_dropped
        stalled.sock.settimeout(GUARD_S)
        assert stalled.was_let_go()
        kept = 0  # what reached the stalled client before it was let go, then the reset
        with contextlib.suppress(ConnectionResetError):
            while data := stalled.sock.recv(1 << 20):
                kept += len(data)
    finally:
        ws.abort()
        if stalled is not None:
            stalled.close()
    reader.stop()
    assert got == n  # the viewer that reads lost nothing to the one that does not
    assert ws.front.counts.clients_cut == 1
    assert 0 < dropped < n
    assert kept < (n - dropped) * (size + 13 + 4)  # never more than was not dropped


def test_a_viewer_on_a_slow_link_is_dropped_for_not_disconnected(monkeypatch):
    """A viewer that keeps taking bytes, slower than the stream, loses messages (counted)
    but stays connected: only one that takes nothing for SEND_TIMEOUT_S is let go. Reading
    4 KiB every 50 ms (~80 kB/s), what the front writes at once (its 64 KiB outbox) takes
    longer than the 0.5 s send timeout to pass below the transport's high-water mark: the
    front cut it at the first timeout."""
    from bench.mcaplog import foxglove_front as front
    from bench.mcaplog.foxglove_ws import WsChannels

    monkeypatch.setattr(front, "OUTBOX_BYTES", 64 * 1024)
    monkeypatch.setattr(front, "SEND_TIMEOUT_S", 0.5)
    monkeypatch.setattr(front, "SEND_BUFFER_BYTES", 32 * 1024)
    ws = WsChannels(port=0)
    slow = None
    try:
        sid = ws.add_schema("bench.Raw", "jsonschema", b'{"type": "object"}')
        cid = ws.add_channel("/can/frames", "json", sid)
        slow = StalledClient(ws.port).subscribe("/can/frames")
        time.sleep(0.5)  # the SDK takes the subscription (a settle, not a bound)
        n = 1500  # 1.5 MB
        ws.add_messages(cid, list(range(1, n + 1)), [b"{}" + b" " * 998] * n, [0] * n)
        slow.sock.settimeout(2.0)  # quiet for 2 s: everything that was kept has come
        got = 0
        with contextlib.suppress(TimeoutError, ConnectionResetError):
            while data := slow.sock.recv(4096):
                got += len(data)
                time.sleep(0.05)
        counts = ws.front.counts
    finally:
        ws.abort()
        if slow is not None:
            slow.close()
    assert counts.clients_cut == 0, (counts, got)
    assert counts.messages_dropped > 0
    assert got > 2 * 64 * 1024  # more than one outbox reached it, at its pace


def test_a_stalled_client_of_the_sdks_own_port_does_not_hold_the_close():
    """The SDK's ``stop`` waits for a stalled client forever; a local process can reach the
    SDK's own port (behind the front) and stall there: closing the stream still ends."""
    from bench.mcaplog.foxglove_ws import WsChannels

    ws = WsChannels(port=0)
    stalled = None
    try:
        sid = ws.add_schema("bench.Raw", "jsonschema", b'{"type": "object"}')
        cid = ws.add_channel("/can/frames", "json", sid)
        stalled = StalledClient(int(ws.server.port), "foxglove.sdk.v1").subscribe()
        time.sleep(0.5)  # the SDK takes the subscription (a settle, not a bound)
        n = 20_000  # 20 MB for a client that reads none of it
        ws.add_messages(cid, list(range(1, n + 1)), [b"{}" + b" " * 998] * n, [0] * n)
        closing = threading.Thread(target=ws.abort, daemon=True)
        closing.start()
        closing.join(GUARD_S)  # without the bound: forever
        assert not closing.is_alive()
        assert ws.closed
    finally:
        if stalled is not None:
            stalled.close()
