"""The calibration benchmark's counts (issue 25): the target over all runs and over the
runs with SPEED_REF, runs without one counted as not calibratable, refusals apart."""

from __future__ import annotations

from benchmarks.calibration import figures


def _fitted(seed: int, err: float, sigma: float) -> dict[str, object]:
    return {
        "seed": seed,
        "odometer": "usable",
        "calibratable": True,
        "error_deg": [err, err, err],
        "sigma_deg": [sigma, sigma, sigma],
        "within": abs(err) <= 0.01,
        "honest": abs(err) <= 3 * sigma,
    }


def test_within_is_counted_of_all_runs_and_of_the_runs_with_speed_ref() -> None:
    runs = [
        _fitted(1, 0.004, 0.002),  # within, honest
        _fitted(2, 0.03, 0.02),  # not within, honest
        _fitted(3, -0.002, 0.003),  # within
        {"seed": 4, "odometer": "poor", "calibratable": True, "within": False, "honest": True,
         "refused": "calibration: the recording does not determine the angles"},
        {"seed": 5, "odometer": "absent", "calibratable": False, "within": False,
         "honest": True, "refused": "calibration: no SPEED_REF in the recording"},
    ]  # fmt: skip
    figs = {f.key: f for f in figures(runs, 1, 1.0, 2)}
    # of 5 runs 2 within; 90 % of 5 is 4.5 -> 5 needed
    assert figs["calibration_within"].value == 2 and figs["calibration_within"].target == 5
    # 4 runs have SPEED_REF: 90 % of 4 is 3.6 -> 4 needed, 2 within
    ref = figs["calibration_within_speed_ref"]
    assert ref.value == 2 and ref.target == 4 and ref.status == "MISS"
    assert "4 runs with SPEED_REF" in ref.label
    assert figs["calibration_not_calibratable"].value == 1
    assert figs["calibration_refused"].value == 1
    assert figs["calibration_honest"].value == 5 and figs["calibration_honest"].status == "PASS"


def test_runs_from_before_the_calibratable_key_count_as_having_speed_ref() -> None:
    old = _fitted(1, 0.001, 0.001)
    del old["calibratable"]
    figs = {f.key: f for f in figures([old], 1, 1.0, 2)}
    assert figs["calibration_within_speed_ref"].value == 1
    assert figs["calibration_not_calibratable"].value == 0


def test_a_run_without_speed_ref_is_shown_as_not_calibratable() -> None:
    from benchmarks.calibration import run_rows

    runs = [
        {"seed": 5, "odometer": "absent", "calibratable": False, "within": False,
         "honest": True, "refused": "calibration: no SPEED_REF in the recording"},
        {"seed": 6, "odometer": "poor", "calibratable": True, "within": False,
         "honest": True, "refused": "calibration: the recording does not determine the angles"},
    ]  # fmt: skip
    rows = run_rows(figures(runs, 5, 1.0, 2))
    assert rows[0][2] == "not calibratable: no SPEED_REF in the recording"
    assert rows[1][2] == "refused: the recording does not determine the angles"
