"""Make docs/img/estimators.png: the device's reference method and the bench's estimator side
by side on one emulated run (run from the repository root: python docs/make_estimator_plot.py).

The run: a train pulls away on level track, climbs +15 permil, runs down a -10 permil grade
and stops on it; 2 ug of sensor noise; ch3's ADC code freezes for 15 s on the down-grade.
Prints the numbers the README quotes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.config import Config  # noqa: E402
from bench.pipeline.steps import Pipeline  # noqa: E402
from devices.base import SourceBatch  # noqa: E402
from devices.emulator import scenario_from_dict, simulate  # noqa: E402

SCENARIO = {
    "seed": 7,
    "duration_s": 150.0,
    "vertical_curve_m": 80.0,
    "track": [
        {"length_m": 300.0, "gradient_permil": 0.0},
        {"length_m": 600.0, "gradient_permil": 15.0},
        {"length_m": 3000.0, "gradient_permil": -10.0},
    ],
    "train": [
        {"duration_s": 5.0},
        {"duration_s": 25.0, "accel_mps2": 0.6},
        {"duration_s": 70.0},
        {"duration_s": 40.0, "accel_mps2": -0.5},
    ],
    "channels": [{"noise_mps2": 2e-5}] * 3,
    "faults": [{"channel": 3, "kind": "stuck", "start_s": 82.0, "end_s": 97.0}],
}


def main(out: Path = ROOT / "docs" / "img" / "estimators.png") -> None:
    sim = simulate(scenario_from_dict(SCENARIO))
    pipe = Pipeline(Config())
    res = np.concatenate([pipe.process(SourceBatch(sim.frames)).results, pipe.finish().results])
    truth = sim.truth["gradient_permil"][res["n"] - sim.truth["counter"][0]]
    t = res["time_s"]
    ref, signed = res["gradient"], res["gradient_signed"]

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6.2), sharex=True, height_ratios=[3, 2])
    stuck = (t >= 82.5) & (t < 97.0)
    for ax in (top, bottom):
        ax.axvspan(82.0, 97.0, color="0.9", zorder=0)
        ax.grid(alpha=0.3)
    top.plot(t, ref, ".", ms=1.2, color="tab:orange", label="reference method (device)")
    top.plot(t, signed, lw=0.8, color="tab:blue", label="bench estimator (signed)")
    top.plot(t, truth, "--", lw=1.0, color="black", label="truth")
    top.text(83, 17, "ch3 stuck:\nexcluded,\ndegraded", fontsize=8, va="top")
    top.set_ylabel("gradient (per mille)")
    top.set_ylim(-22, 22)
    top.legend(loc="lower left", fontsize=8, ncols=3)
    top.set_title("Same emulated run, two estimators", fontsize=10)
    with np.errstate(invalid="ignore"):
        bottom.semilogy(t, np.abs(ref - truth), ".", ms=1.2, color="tab:orange")
        bottom.semilogy(t, np.abs(signed - truth), ".", ms=1.2, color="tab:blue")
    bottom.set_ylim(1e-4, 100)
    bottom.set_ylabel("|error| (per mille)")
    bottom.set_xlabel("time (s)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")

    def stats(mask: np.ndarray, label: str) -> None:
        valid = mask & np.isfinite(ref)
        e_ref = np.abs(ref - truth)[valid]
        e_sig = np.abs(signed - truth)[mask & np.isfinite(signed)]
        print(
            f"{label}: reference valid {valid.sum() / mask.sum():.0%}, p99 |error| "
            f"{np.percentile(e_ref, 99) if len(e_ref) else float('nan'):.3g} permil; "
            f"bench estimator p99 |error| {np.percentile(e_sig, 99):.3g} permil"
        )

    stats((t >= 1) & (t < 5), "standstill, level")
    stats((t >= 45) & (t < 74), "cruise on +15 permil")
    stats(stuck, "cruise on -10 permil, ch3 stuck")


if __name__ == "__main__":
    main()
