"""Check kinds against hand-made runs: values computed by hand, not by the code under test."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from bench.acceptance.checks.base import CheckSpec
from bench.acceptance.checks.registry import KINDS, overall, run_check
from bench.acceptance.model import FaultInfo, RunData, StepWindow
from bench.records.events import EventKind, concat_events, make_events
from bench.records.results import RESULT_DTYPE

RATE = 100.0
N_REF = 250  # the first sample's counter: k = n - 250


def results(n: int = 1000) -> np.ndarray:
    r = np.zeros(n, dtype=RESULT_DTYPE)
    r["n"] = N_REF + np.arange(n)
    r["t"] = 1000.0 + np.arange(n) / RATE + 0.002  # receive time: 2 ms after the instant
    r["gradient"] = 20.0
    r["gradient_signed"] = 20.0
    r["gradient_ls"] = 20.0
    r["valid"] = True
    r["votes"] = True
    r["present"] = True
    return r


def run(res: np.ndarray | None = None, **kw: Any) -> RunData:
    res = results() if res is None else res
    kw.setdefault("truth_gradient", np.full(1000, 20.0))
    return RunData(
        results=res, events=kw.pop("events", make_events(0, [])), rate_hz=RATE, n_ref=N_REF, **kw
    )


def spec(kind: str, from_s: float | None = None, to_s: float | None = None, **params: Any):
    return CheckSpec(1, f"{kind} check", kind, params, from_s, to_s)


def test_gradient_error_statistics_by_hand() -> None:
    r = results()
    r["gradient"][100] = 21.0  # +1 permil at 1.00 s
    r["gradient"][200] = 19.5  # -0.5 at 2.00 s
    r["gradient"][300] = np.nan  # invalid samples are availability's business
    m = run_check(spec("gradient_error", max_permil=0.8), run(r))
    assert m.value == pytest.approx(1.0)
    assert m.verdict == "fail" and m.margin == pytest.approx(-0.2)
    assert "by 0.2 permil" in m.detail and "1.000 s" in m.detail
    assert m.extra["samples"] == 999
    m = run_check(spec("gradient_error", max_permil=0.8, statistic="rms"), run(r))
    assert m.value == pytest.approx(math.sqrt((1.0 + 0.25) / 999))
    m = run_check(spec("gradient_error", max_permil=0.8, statistic="bias"), run(r))
    assert m.value == pytest.approx(0.5 / 999)
    # window [1.5, 5): only the -0.5 sample is in
    m = run_check(spec("gradient_error", 1.5, 5.0, max_permil=0.8, warn_permil=0.4), run(r))
    assert m.value == pytest.approx(0.5) and m.verdict == "warn"
    assert m.extra["samples"] == 349


def test_unsigned_methods_compare_with_magnitude() -> None:
    r = results()
    r["gradient_signed"] = -20.0
    t = run(r, truth_gradient=np.full(1000, -20.0))
    assert run_check(spec("gradient_error", max_permil=0.1), t).value == 0.0
    signed_truth = run_check(spec("gradient_error", max_permil=0.1, truth="signed"), t)
    assert signed_truth.value == pytest.approx(40.0) and signed_truth.verdict == "fail"
    assert run_check(spec("gradient_error", max_permil=0.1, estimator="signed"), t).value == 0


def test_gradient_error_empty_window() -> None:
    r = results()
    r["gradient"][:] = np.nan
    m = run_check(spec("gradient_error", max_permil=1.0), run(r))
    assert m.verdict == "fail" and m.value is None
    m = run_check(spec("gradient_error", max_permil=1.0, allow_empty=True), run(r))
    assert m.verdict == "pass" and m.value == 0.0
    no_truth = run(truth_gradient=None)
    assert run_check(spec("gradient_error", max_permil=1.0), no_truth).verdict == "error"


def test_availability_counts_lost_samples() -> None:
    r = results()
    r["valid"][10:20] = False
    r = np.delete(r, np.arange(500, 530))  # 30 samples never arrived
    m = run_check(spec("availability", min_fraction=0.99), run(r))
    assert m.value == pytest.approx((1000 - 10 - 30) / 1000)
    assert m.verdict == "fail" and "960 of 1000" in m.detail
    m = run_check(spec("availability", 0.0, 1.0, min_fraction=0.8, warn_fraction=0.95), run(r))
    assert m.value == pytest.approx(0.9) and m.verdict == "warn"
    r["gradient_signed"][:] = np.nan
    m = run_check(spec("availability", estimator="signed", min_fraction=0.5), run(r))
    assert m.value == 0.0 and m.verdict == "fail"


FAULT = FaultInfo(1, "dropout", (3,), "#1 dropout ch3 4-6 s", 4.0, 6.0, onset_k=400, affected=600)


def test_fault_detected_by_gap_event_and_by_crc_time() -> None:
    gap = make_events(EventKind.GAP, 1004.05, 3, N_REF + 405)
    m = run_check(
        spec("fault_detected", channel=3, within_samples=10), run(events=gap, faults=(FAULT,))
    )
    assert m.value == 5 and m.verdict == "pass"
    assert "GAP ch3 at sample 405" in m.detail and "50 ms" in m.detail
    # a CRC error names no sample: it is placed at the result received nearest in time
    crc = make_events(EventKind.CRC_ERROR, 1004.121, 3, -1, 0x103)
    m = run_check(
        spec("fault_detected", channel=3, within_samples=10), run(events=crc, faults=(FAULT,))
    )
    assert m.value == 12 and m.verdict == "fail" and "by 2 samples" in m.detail
    # a flag of another channel, or before the onset, does not count
    other = concat_events(
        [
            make_events(EventKind.GAP, 1004.2, 2, N_REF + 420),
            make_events(EventKind.GAP, 1003.0, 3, N_REF + 300),
        ]
    )
    m = run_check(
        spec("fault_detected", channel=3, within_samples=10), run(events=other, faults=(FAULT,))
    )
    assert m.verdict == "fail" and m.value is None and "never flagged" in m.detail


def test_fault_detected_by_votes_and_exclusion_columns() -> None:
    r = results()
    # ch3 alone bad: v1 and v3 fail (the two votes comparing s1 = g12, which ch3 is not in)
    r["votes"][403:] = [False, True, False]
    m = run_check(spec("fault_detected", channel=3, within_samples=10), run(r, faults=(FAULT,)))
    assert m.value == 3 and "VOTE_FAIL" in m.detail
    # the v1+v2 pattern points at ch1, not ch3
    r["votes"][403:] = [False, False, True]
    m = run_check(spec("fault_detected", channel=3, within_samples=10), run(r, faults=(FAULT,)))
    assert m.value is None
    r["excluded"][407:] = 3
    m = run_check(spec("fault_detected", channel=3, within_samples=10), run(r, faults=(FAULT,)))
    assert m.value == 7 and "EXCLUDED" in m.detail
    only_votes = spec("fault_detected", channel=3, within_samples=10, flagged_by=("VOTE_FAIL",))
    assert run_check(only_votes, run(r, faults=(FAULT,))).value is None
    silent = FaultInfo(2, "loss", (3,), "#2", 4.0, 6.0, onset_k=None, affected=0)
    m = run_check(spec("fault_detected", fault=2, within_samples=10), run(r, faults=(silent,)))
    assert m.verdict == "fail" and "no effect" in m.detail


def test_no_frame_loss() -> None:
    ok = run(frames_sent=3000, frames_received=3000, frames_logged=3000)
    m = run_check(spec("no_frame_loss"), ok)
    assert m.value == 0 and m.verdict == "pass" and "logged 3000" in m.detail
    short_log = run(frames_sent=3000, frames_received=3000, frames_logged=2990)
    m = run_check(spec("no_frame_loss"), short_log)
    assert m.value == 10 and m.verdict == "fail" and "by 10 frames" in m.detail
    board = run(frames_sent=None, frames_received=3000, frames_logged=3000, frames_dropped=4)
    assert run_check(spec("no_frame_loss", max_frames=5), board).value == 4
    # frames the kernel dropped at a full socket buffer (SOCKET_OVERFLOW notices, 2 + 9)
    # are lost too, though the pipeline never saw them to count them received
    kernel = make_events(EventKind.SOCKET_OVERFLOW, [1001.0, 1002.0], 0, -1, [2, 9])
    real = run(frames_sent=None, frames_received=3000, frames_logged=3000, events=kernel)
    m = run_check(spec("no_frame_loss"), real)
    assert m.value == 11 and m.verdict == "fail" and "dropped by the kernel 11" in m.detail


def test_vote_failures_jump_events() -> None:
    r = results()
    r["votes"][10:15, 0] = False
    r["votes"][12:20, 2] = False
    m = run_check(spec("vote_failures", max_count=9), run(r))
    assert m.value == 10 and m.verdict == "fail" and m.extra["per_vote"] == [5, 0, 8]
    assert run_check(spec("vote_failures", vote=3, max_count=9), run(r)).value == 8
    r["gradient"][50] = 23.0
    r["gradient"][51] = np.nan
    r["gradient"][52] = 10.0  # not consecutive with 50: no step counted across the hole
    m = run_check(spec("gradient_jump", max_permil=5.0), run(r))
    assert m.value == pytest.approx(10.0)  # 10 -> 20 at samples 52 -> 53
    assert m.verdict == "fail" and m.extra["at_s"] == pytest.approx(0.52)
    ev = concat_events(
        [
            make_events(EventKind.CRC_ERROR, [1001.0, 1002.0, 1009.0], 2, -1, 0x102),
            make_events(EventKind.SAMPLES_LOST, 1003.0, 0, N_REF + 300, 7),
            make_events(EventKind.GAP, 1004.0, 1, N_REF + 400),
        ]
    )
    m = run_check(
        spec("event_count", 0.0, 5.0, events=("CRC_ERROR", "SAMPLES_LOST")), run(events=ev)
    )
    assert m.value == 2 + 7 and m.extra["counts"] == {"CRC_ERROR": 2, "SAMPLES_LOST": 1}
    assert run_check(spec("event_count", events=("GAP",), channel=2), run(events=ev)).value == 0


def test_step_gradient() -> None:
    r = results()
    r["gradient"][200:400] = 10.3  # step 1 reads 10.3 ...
    r["gradient"][600:800] = 29.9
    steps = (
        StepWindow(1, "ten", -10.0, 1.5, 2.0, 4.0),  # ... for -10: the method has no sign
        StepWindow(2, "skipped", 5.0, 4.0, 4.5, 5.0, answer="skip"),
        StepWindow(3, "thirty", 30.0, 5.5, 6.0, 8.0),
    )
    m = run_check(spec("step_gradient", max_permil=0.25, step=1), run(r, steps=steps))
    assert m.value == pytest.approx(0.3) and m.verdict == "fail"
    m = run_check(spec("step_gradient", max_permil=0.25, step=3), run(r, steps=steps))
    assert m.value == pytest.approx(0.1) and m.verdict == "pass"
    m = run_check(
        spec("step_gradient", max_permil=0.25, estimator="signed", step=1), run(r, steps=steps)
    )
    assert m.value == pytest.approx(30.0)  # the signed estimate read +20 on a -10 step
    m = run_check(spec("step_gradient", max_permil=0.5), run(r, steps=steps))
    assert m.verdict == "fail" and m.value is None and "skipped" in m.detail


def test_latency_only_live_and_overall() -> None:
    m = run_check(spec("latency", max_ms=10.0), run())
    assert m.verdict == "skip"
    m = run_check(spec("latency", max_ms=10.0, warn_ms=5.0), run(latency_ms=(2.0, 7.0)))
    assert m.value == 7.0 and m.verdict == "warn"
    assert overall([m]) == "pass"
    failing = run_check(spec("latency", max_ms=1.0), run(latency_ms=(2.0, 7.0)))
    assert overall([m, failing]) == "fail"
    broken = run_check(spec("no_frame_loss"), None)  # type: ignore[arg-type]
    assert broken.verdict == "error" and "the check itself failed" in broken.detail
    assert overall([failing, broken]) == "error"


def test_every_kind_has_a_unit_and_a_limit_key() -> None:
    for name, kind in KINDS.items():
        assert kind.unit
        assert kind.params[kind.limit.key].type in ("number", "integer"), name
