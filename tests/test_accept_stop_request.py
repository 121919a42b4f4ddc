"""A SIGTERM whose raise Python swallowed still ends `bench accept` (issue 27).

`.ci/run` on f942915 saw `bench accept --realtime` print the Stopped traceback on SIGTERM
and then run on to the end of its 120 s plan: the signal had arrived while a finaliser ran,
and Python reports an exception raised there ("Exception ignored in") instead of raising it.
The handler therefore keeps the reason as well, and the run's loops look at it.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from bench.acceptance.plan import parse_plan
from bench.acceptance.runner import Options, Stopped, StopRequest, run_plan
from bench.commands.accept import stopped_by_signals
from tests.test_hostile_records import PLAN as RECORDS_PLAN

PLAN = RECORDS_PLAN.format(d=2.0)


class SignalledWhileFinalised:
    """Sends this process SIGTERM from its finaliser and waits there for the handler."""

    def __del__(self) -> None:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.2)  # the handler runs here, inside the finaliser


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_signal_raised_inside_a_finaliser_is_kept_for_the_run():
    request = StopRequest()
    with stopped_by_signals(request):
        obj = SignalledWhileFinalised()
        del obj  # Python prints "Exception ignored in ..." and goes on: nothing raised here
        assert request.reason == "stopped by SIGTERM"
        with pytest.raises(Stopped, match="stopped by SIGTERM"):
            request.check()


def test_a_run_whose_stop_was_swallowed_ends_in_error_with_its_records(tmp_path: Path):
    out = tmp_path / "acc"
    plan = parse_plan(PLAN, "stop.toml", tmp_path / "stop.toml")
    request = StopRequest(reason="stopped by SIGTERM")  # as the handler leaves it
    outcome = run_plan(plan, Options(out_dir=out, stop=request, plots=False))
    assert outcome.error == "stopped by SIGTERM"
    assert outcome.verdict == "error"
    record = json.loads((out / "record.json").read_text())
    assert record["verdict"] == "error" and record["error"] == "stopped by SIGTERM"
    assert (out / "junit.xml").stat().st_size > 0


def test_no_request_no_error(tmp_path: Path):
    """The same plan without a stop request passes: the error above is the request's."""
    plan = parse_plan(PLAN, "stop.toml", tmp_path / "stop.toml")
    outcome = run_plan(plan, Options(out_dir=tmp_path / "acc", plots=False))
    assert outcome.error is None and outcome.verdict == "pass"
