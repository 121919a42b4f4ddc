"""Per-pair panel: g12/g23/g13, the three votes, the weights and the final gradient, large.

This is the centre of the screen: it shows one fusion result row exactly as computed
(reference method, METHOD.md 1-3), next to the bench's own signed estimate (section 5)
with its 1-sigma and its mean, min and max over the last few seconds,
so an engineer sees at a glance when and why the reference method loses the answer.
"""

from __future__ import annotations

import math

import numpy as np
from rich.table import Table
from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widgets import Digits, Static

from bench.pipeline.warmup import WarmUpStatus
from bench.records.results import VOTE_SLOPES
from bench.tui.panels import MISSING, grade_state, num

PAIR_NAMES = ("g12", "g23", "g13")
VOTE_NAMES = ("v1", "v2", "v3")
STATE_LABEL = {
    "valid": "VALID",
    "degraded": "DEGRADED",
    "invalid": "INVALID",
    "none": "NO DATA",
}


def pair_table(row: np.void | None, tolerance: float) -> Table:
    """Slope value, weight and vote per line (vote k compares the slopes named beside it)."""
    table = Table(box=None, pad_edge=False, padding=(0, 1), expand=False, show_edge=False)
    table.add_column("pair", style="bold")
    table.add_column("‰", justify="right", min_width=8)
    table.add_column("weight", justify="right")
    table.add_column("vote")
    table.add_column("", justify="center", min_width=6)
    table.add_column("|Δ| ‰", justify="right")
    for k in range(3):
        p, q = VOTE_SLOPES[k]
        cmp = f"{VOTE_NAMES[k]} {PAIR_NAMES[p][1:]}~{PAIR_NAMES[q][1:]}"
        if row is None:
            table.add_row(PAIR_NAMES[k], MISSING, MISSING, cmp, Text(MISSING), MISSING)
            continue
        slopes = row["slopes"]
        ok = bool(row["votes"][k])
        mark = (
            Text(" PASS ", style="bold black on green")
            if ok
            else Text(" FAIL ", style="bold white on red")
        )
        delta = abs(float(slopes[p]) - float(slopes[q]))
        delta_text = Text(num(delta, ".3f"), style="" if ok else "red")
        table.add_row(
            PAIR_NAMES[k],
            num(slopes[k], ".3f"),
            num(row["weights"][k], ".3f"),
            cmp,
            mark,
            delta_text,
        )
    return table


def final_text(row: np.void | None) -> str:
    """The final gradient for the Digits widget (never negative: the method has no sign)."""
    if row is None or not bool(row["valid"]) or not math.isfinite(float(row["gradient"])):
        return " --.--"
    return f"{float(row['gradient']):6.2f}"  # fixed width: no relayout on every update


WINDOW_S = 5.0
"""Span of the windowed mean, min and max shown under "ours" (board time up to the row)."""


def ours_text(row: np.void | None) -> tuple[str, str]:
    """Our estimator's figure for the Digits widget and what it is: the 1-sigma
    ('±0.12 σ') when given, 'withheld' (sigma above the limit), '|LS|' or 'n/a'."""
    if row is None:
        return " --.--", "n/a"
    signed = float(row["gradient_signed"])
    sigma = float(row["gradient_sigma"])
    if math.isfinite(signed):
        return f"{signed:+6.2f}", f"±{num(sigma, '.2f')} σ"
    ls = float(row["gradient_ls"])
    if math.isfinite(sigma):
        return " --.--", "withheld"
    if math.isfinite(ls):
        return f"{ls:6.2f}", "|LS|"
    return " --.--", "n/a"


def ours_window(
    rows: np.ndarray | None, row: np.void | None, span_s: float = WINDOW_S
) -> tuple[float, float, float] | None:
    """(mean, min, max) of the given estimator gradients over the ``span_s`` up to ``row``,
    None when there are none."""
    if rows is None or row is None or len(rows) == 0:
        return None
    t = rows["time_s"]
    t1 = float(row["time_s"])
    sel = (t <= t1) & (t > t1 - span_s)
    g = rows["gradient_signed"][sel]
    g = g[np.isfinite(g)]
    if len(g) == 0:
        return None
    return float(np.mean(g)), float(np.min(g)), float(np.max(g))


def ours_detail(row: np.void | None, window: tuple[float, float, float] | None = None) -> Text:
    """Two lines on the estimator: the windowed mean, min and max, then LS magnitude,
    residual, exclusion and the odometer's state."""
    if row is None:
        return Text("")
    text = Text(f"σ {num(row['gradient_sigma'], '.2f')} ‰  ")
    if window is None:
        text.append(f"{WINDOW_S:g} s: {MISSING}\n")
    else:
        mean, lo, hi = window
        text.append(f"{WINDOW_S:g} s: mean {mean:+.2f}  min {lo:+.2f}  max {hi:+.2f}\n")
    parts = [
        f"LS {num(row['gradient_ls'], '.2f')}‰",
        f"res {num(row['residual'], '.4f')}",
    ]
    text.append("ours: " + "  ".join(parts), style="dim")
    ex = int(row["excluded"])
    if ex:
        text.append(f"  ch{ex} excluded", style="bold yellow")
    if bool(row["degraded"]):
        text.append("  degraded", style="yellow")
    if bool(row["odometer_suspect"]):
        text.append("  odometer suspect", style="bold yellow")
    if bool(row["coasting"]):
        text.append("  coasting", style="yellow")
    return text


def preparing_detail(status: WarmUpStatus) -> Text:
    """The estimator's two lines while its kernel is prepared: how long so far, and why."""
    text = Text(status.headline(), style="bold yellow")
    text.append("\n" + status.detail(), style="bold red" if status.error else "dim")
    return text


class PairsPanel(Vertical):
    """The per-pair values of one result row (the newest, or the one the replay cursor is on)."""

    def compose(self) -> ComposeResult:
        yield Static(pair_table(None, 0.0), id="pair-table")
        with Horizontal(id="final-row"):
            yield Digits(final_text(None), id="final")
            yield Static("", id="final-state")
            yield Digits(" --.--", id="ours")
            yield Static("ours\nn/a", id="ours-label")
        yield Static("", id="ours-detail")

    def on_mount(self) -> None:
        self.border_title = "Per pair"
        self.values: dict[str, str] = {}

    def show(
        self,
        row: np.void | None,
        tolerance: float,
        *,
        cursor: bool = False,
        rows: np.ndarray | None = None,
        preparing: WarmUpStatus | None = None,
    ) -> None:
        """Show ``row``; ``rows`` (recent results) feed the windowed mean, min and max;
        ``preparing``: the estimator's kernel is still being prepared (its figures pending)."""
        state = grade_state(row)
        where = "at cursor" if cursor else "latest"
        if row is not None:
            self.border_title = (
                f"Per pair · sample {int(row['n'])} ({where}) · tol ±{tolerance:g} ‰"
            )
        else:
            self.border_title = f"Per pair · tol ±{tolerance:g} ‰"
        self.query_one("#pair-table", Static).update(pair_table(row, tolerance), layout=False)
        final = self.query_one("#final", Digits)
        final.update(final_text(row))
        for s in ("valid", "degraded", "invalid", "none"):
            final.set_class(s == state, s)
        passed = 0 if row is None else int(np.count_nonzero(row["votes"]))
        label = self.query_one("#final-state", Static)
        label.update(Text(f"‰\n{STATE_LABEL[state]}\n{passed}/3 votes"), layout=False)
        for s in ("valid", "degraded", "invalid", "none"):
            label.set_class(s == state, s)
        ours, kind = ours_text(row) if preparing is None else (" --.--", "preparing")
        ours_w = self.query_one("#ours", Digits)
        ours_w.update(ours)
        ours_w.set_class(kind in ("n/a", "preparing") or kind.startswith("withheld"), "none")
        ours_w.set_class(row is not None and bool(row["degraded"]), "degraded")
        self.query_one("#ours-label", Static).update(f"‰ ours\n{kind}", layout=False)
        window = ours_window(rows, row) if preparing is None else None
        detail = ours_detail(row, window) if preparing is None else preparing_detail(preparing)
        self.query_one("#ours-detail", Static).update(detail, layout=False)
        self.values = {"final": final_text(row).strip(), "state": state, "ours": ours.strip()}
        self.values["ours_kind"] = kind
        if window is not None:
            shown = (num(v, ".3f") for v in window)
            self.values.update(zip(("ours_mean", "ours_min", "ours_max"), shown, strict=True))
        if row is not None:
            for k in range(3):
                self.values[PAIR_NAMES[k]] = num(row["slopes"][k], ".3f")
                self.values[f"w{PAIR_NAMES[k][1:]}"] = num(row["weights"][k], ".3f")
                self.values[VOTE_NAMES[k]] = "PASS" if bool(row["votes"][k]) else "FAIL"
