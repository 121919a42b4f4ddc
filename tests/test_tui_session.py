"""The Recorder: the TUI's one sink that starts and stops MCAP files under a running runner."""

from __future__ import annotations

import threading

from bench.live.session import Recorder
from bench.pipeline.steps import StepOutput
from protocol.frames import empty_frames
from tests.test_tui_support import FakeSink


class CountingSink(FakeSink):
    def __init__(self, path: str) -> None:
        super().__init__(path)
        self.closes = 0

    def close(self) -> None:
        self.closes += 1
        super().close()


def step(n: int) -> StepOutput:
    return StepOutput(frames=empty_frames(n))


def test_a_stopped_file_gets_nothing_more_and_is_closed_once() -> None:
    first = CountingSink("a.mcap")
    rec = Recorder(lambda: CountingSink("b.mcap"), first)
    rec.write(step(3))
    old = rec.detach()
    rec.write(step(5))  # between two files: goes nowhere
    assert old is first and first.frames == 3 and not rec.active
    rec.finish(old)
    rec.finish(old)
    assert first.closes == 1
    assert rec.last_status is not None and rec.last_status.path == "a.mcap"
    assert rec.start().name == "b.mcap"
    rec.write(step(2))
    rec.close()
    assert [str(p) for p in rec.files] == ["a.mcap", "b.mcap"]


def test_shutdown_closes_a_file_whose_close_has_not_run_yet() -> None:
    first = CountingSink("a.mcap")
    rec = Recorder(None, first)
    old = rec.detach()
    rec.close()  # the runner stopped before the UI's worker got to it
    assert first.closes == 1
    rec.finish(old)  # the late worker does nothing
    assert first.closes == 1


def test_shutdown_waits_for_a_close_in_progress() -> None:
    release = threading.Event()

    class SlowSink(CountingSink):
        def close(self) -> None:
            release.wait(5)
            super().close()

    slow = SlowSink("slow.mcap")
    rec = Recorder(None, slow)
    old = rec.detach()
    worker = threading.Thread(target=rec.finish, args=(old,))
    worker.start()
    closer = threading.Thread(target=rec.close)
    closer.start()
    closer.join(0.2)
    assert closer.is_alive()  # quitting waits for the file to be finished
    release.set()
    closer.join(5)
    worker.join(5)
    assert not closer.is_alive() and slow.closes == 1


def test_steps_go_through_while_a_new_file_opens() -> None:
    """Opening a recording starts a writer process and waits for it (seconds on a loaded
    machine): the processing thread's writes must not wait for that. The open is held here
    until the writes are done; were it under the lock they go through, they would hang."""
    opening, release = threading.Event(), threading.Event()

    def open_slowly() -> CountingSink:
        opening.set()
        assert release.wait(60)  # a hang guard for the test's own end, not a bound
        return CountingSink("b.mcap")

    rec = Recorder(open_slowly, None)
    starter = threading.Thread(target=rec.start)
    starter.start()
    try:
        assert opening.wait(60)
        writer = threading.Thread(target=lambda: [rec.write(step(1)) for _ in range(100)])
        writer.start()
        writer.join(60)  # with the bug: still waiting when the guard runs out
        assert not writer.is_alive(), "a write waited for the file to open"
        assert not rec.active  # the file still opens: those steps went nowhere
    finally:
        release.set()
        starter.join(60)
    rec.write(step(2))
    assert rec.active and rec.path is not None and rec.path.name == "b.mcap"
    rec.close()
