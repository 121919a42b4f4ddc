"""The car body's vertical velocity states (body_velocity_tau_s) on the shipped rough ride
(metro_vibration: a 2.5 Hz bounce plus broadband track irregularity), scored against the
emulator's truth: more of the run given, no more of it wrong, the sigma still honest."""

from __future__ import annotations

import dataclasses

import pytest

import benchmarks.accuracy as accuracy


def _figures(monkeypatch: pytest.MonkeyPatch, tau: float) -> dict[str, float | None]:
    as_built = accuracy.scenario_config

    def config(sc):  # type: ignore[no-untyped-def]
        c = as_built(sc)
        return dataclasses.replace(
            c, estimator=dataclasses.replace(c.estimator, body_velocity_tau_s=tau)
        )

    monkeypatch.setattr(accuracy, "scenario_config", config)
    run = accuracy.replay_run("metro_vibration")
    return accuracy.scores(run.estimator, run.n, run.truth_permil, run.sigma, signed=True)


def test_a_bounded_body_velocity_lets_w_give_more_of_a_rough_ride(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    with_z = _figures(monkeypatch, 0.2)
    block_noise = _figures(monkeypatch, 0.0)  # the vibration as block noise only
    assert with_z["avail"] >= 92.0 and with_z["avail"] >= block_noise["avail"] + 2.5
    assert with_z["wrong"] <= 0.25  # > 1 permil wrong, % of the run (target 0.5)
    assert with_z["cover"] >= 97.0  # within 2 sigma, % of what is given
    assert with_z["rms"] <= 0.2
