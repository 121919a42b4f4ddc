"""The explicit model's panel (`--lag`): what the live model learns that the results do not
carry -- the odometer's wheel-diameter error E, the car body's pitch compliance C and each
channel's bias -- each with its 1-sigma from the model's P, the fixed-lag gradient, and
whether the model keeps up (its queue, and the pushes a full one dropped)."""

from __future__ import annotations

import math

from rich.text import Text
from textual.widgets import Static

from bench.live.view import ModelView
from bench.tui.panels import MISSING, labelled, num

MG_MPS2 = 9.80665e-3
"""One milli-g in m/s^2: the biases are shown in mg, as a calibration sheet gives them."""


def model_lines(v: ModelView) -> Text:
    """Five lines, label first (see the module docstring)."""
    lines: list[tuple[str, Text | str]] = []
    row = v.latest
    if v.error:
        lines.append(("model", Text(v.error, style="bold red")))
    elif row is None:
        lines.append(("model", Text("preparing…" if not v.ready else "no block yet", "dim")))
    else:
        e, es = 100.0 * float(row["wheel_error"]), 100.0 * float(row["wheel_error_sigma"])
        lines.append(("wheel", f"{num(e, '+.2f')} ± {num(es, '.2f')} %"))
        c, cs = float(row["compliance"]), float(row["compliance_sigma"])
        lines.append(("pitch", f"{num(c, '+.3f')} ± {num(cs, '.3f')} °/(m/s²)"))
        b = [float(x) / MG_MPS2 for x in row["bias"]]
        bs = [float(x) / MG_MPS2 for x in row["bias_sigma"]]
        lines.append(("bias", " ".join(num(x, "+.2f") for x in b) + " mg"))
        lines.append(("  ±", " ".join(num(x, ".2f") for x in bs) + " mg"))
    lag = MISSING
    if len(v.lagged):
        g, s = float(v.lagged[-1, 1]), float(v.lagged[-1, 2])
        lag = f"{num(g, '+.2f')} ± {num(s, '.2f')} ‰" if math.isfinite(g) else MISSING
    state = Text(f"{lag}  q {v.queued_samples} drop ")
    state.append(str(v.dropped_pushes), style="bold red" if v.dropped_pushes else "")
    lines.append((f"lag {v.lag_s:g}s", state))
    return labelled(lines, 7)


class ModelPanel(Static):
    """Hidden unless the run has the live model."""

    def on_mount(self) -> None:
        self.border_title = "Model"

    def show(self, view: ModelView | None) -> None:
        self.set_class(view is not None, "shown")
        if view is not None:
            self.update(model_lines(view), layout=False)
