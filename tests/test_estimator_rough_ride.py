"""The car body's vertical velocity states (body_velocity_tau_s) on the shipped rough ride
(metro_vibration: a 2.5 Hz bounce plus broadband track irregularity), scored against the
emulator's truth: more of the run given, no more of it wrong, the sigma still honest."""

from __future__ import annotations

import re
from pathlib import Path

import benchmarks.accuracy as accuracy
from benchmarks.common import ROOT


def _figures(scenario: str = "metro_vibration", **settings: float) -> dict[str, float | None]:
    run = accuracy.replay_run(scenario, **settings)
    return accuracy.scores(run.estimator, run.n, run.truth_permil, run.sigma, signed=True)


def test_a_bounded_body_velocity_lets_w_give_more_of_a_rough_ride() -> None:
    with_z = _figures(body_velocity_tau_s=0.05)
    block_noise = _figures(body_velocity_tau_s=0.0)  # the vibration as block noise only
    assert with_z["avail"] >= 92.0 and with_z["avail"] >= block_noise["avail"] + 2.5
    assert with_z["wrong"] <= 0.25  # > 1 permil wrong, % of the run (target 0.5)
    assert with_z["cover"] >= 97.0  # within 2 sigma, % of what is given
    assert with_z["rms"] <= 0.25  # target 0.3


def test_on_the_bounce_alone_a_curve_start_is_never_given_confidently_wrong(
    tmp_path: Path,
) -> None:
    """The same run with the vibration issue 15 describes (the 2.5 Hz bounce, no broadband):
    the curve detector's first guess of k is often 50 % off there, and the age it infers
    for the step is uncertain too; s's variance says so, so nothing > 1 permil wrong is
    given (it was 0.39 % of the run, up to 2.1 permil, before the age's uncertainty
    counted)."""
    text = (ROOT / "devices" / "scenarios" / "metro_vibration.toml").read_text()
    for key in ("broadband_vertical_mps2", "broadband_longitudinal_mps2"):
        text, n = re.subn(rf"^{key} = .*$", f"{key} = 0.0", text, flags=re.M)
        assert n == 1
    path = tmp_path / "bounce_only.toml"
    path.write_text(text)
    run = accuracy.replay_run(str(path))
    s = accuracy.scores(run.estimator, run.n, run.truth_permil, run.sigma, signed=True)
    assert s["avail"] >= 97.0
    assert s["wrong"] == 0.0 and s["max"] < 1.0
    # and the sigma is honest there: what the notch takes out of w leaves a share of its
    # power in w's R (without it 88 % within 2 sigma, k following the notch's leftovers)
    assert s["cover"] >= 95.0


def test_below_the_speed_where_w_shows_every_curve_k_walks_faster_so_the_demo_is_not_wrong() -> (
    None
):
    """The demo's +20 permil hump at 14 m/s: its 100 m curves give v^2/R = v^2 k / g =
    196 * 1.96e-3 / 9.81 = 0.039 m/s^2, under what the detector can tell from the ride, so
    k must follow them by its walk; at the cruise walk it lagged and overshot by up to
    1.8 permil at a sigma of 0.2 (measured 0.44 % of the run > 1 permil wrong, 0.11 %
    with the walk growing below curve_visible_speed_mps)."""
    faster = _figures("demo")
    cruise = _figures("demo", curve_visible_speed_mps=0.0)
    assert faster["wrong"] <= 0.2 and faster["wrong"] <= 0.5 * cruise["wrong"]
    assert faster["avail"] >= cruise["avail"] - 1.5  # measured 80.2 against 81.4 %
    assert faster["cover"] >= 96.0
