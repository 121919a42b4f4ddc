"""Gradient history: the final gradient, the three pair traces and our signed estimate, and
with `--lag` the live model's fixed-lag smoothed gradient (drawn at its own, earlier, time).

The series are cut to the selected window and thinned to about two points per column in
the poller thread (:func:`prepare_series`), so the UI thread only draws a few hundred points.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from rich.text import Text
from textual.widgets import Static
from textual_plotext.plot import Plot

from protocol.layout import TICK_S

WINDOWS_S = (10.0, 30.0, 60.0, 300.0)
"""Selectable plot windows (the runner keeps 60000 results: 5 min at 200 Hz, 1 min at 1 kHz)."""

TRACES = (
    ("g12", "g12", "#00c8ff"),
    ("g23", "g23", "#d070ff"),
    ("g13", "g13", "#ffc400"),
    ("signed", "ours", "#50d050"),
    ("gradient", "final", "#ffffff"),
)
"""(column, legend label, colour), in drawing order: the final gradient last, on top. Colours
are RGB, not colour names: plotext's names go through the terminal's palette (white and
yellow came out alike, magenta as the FAIL pink), these reach the screen as written."""


LAGGED_TRACE = ("lagged", "lag", "#ff8c40")
"""The live model's fixed-lag gradient (`--lag`): drawn under the final gradient."""


def rgb(color: str) -> tuple[int, int, int]:
    """'#rrggbb' as the (r, g, b) plotext takes."""
    return (int(color[1:3], 16), int(color[3:5], 16), int(color[5:7], 16))


def legend_markup(lag_s: float | None = None) -> str:
    """The legend in the panel title, in the traces' own colours (final first); with
    ``lag_s`` the model's lagged line too."""
    order = sorted(TRACES, key=lambda tr: tr[0] != "gradient")
    text = " ".join(f"[{color}]{label}[/]" for _, label, color in order)
    if lag_s is not None:
        text += f" [{LAGGED_TRACE[2]}]{LAGGED_TRACE[1]} {lag_s:g} s[/]"
    return text


def nice_step(span: float, max_ticks: int) -> float:
    """The smallest 1-2-5 x 10^k step that cuts ``span`` into at most ``max_ticks`` parts."""
    span = max(span, 1e-9)
    raw = span / max(1, max_ticks)
    mag = 10.0 ** math.floor(math.log10(raw))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * mag >= raw * (1 - 1e-9):
            return m * mag
    return 10.0 * mag


def y_ticks(lo: float, hi: float, rows: int) -> tuple[list[float], list[str]]:
    """Round tick values (multiples of a 1-2-5 step, so 0 whenever it is in range) about
    three or more rows apart (closer, the row rounding puts some labels on adjacent rows and
    the axis reads uneven), labelled with as many decimals as the step needs."""
    step = nice_step(hi - lo, max(3, rows // 3))
    first = math.ceil(lo / step - 1e-9)
    last = math.floor(hi / step + 1e-9)
    ticks = [k * step for k in range(first, last + 1)]
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    labels = [f"{0.0 if abs(t) < step / 2 else t:.{decimals}f}" for t in ticks]
    return [0.0 if abs(t) < step / 2 else t for t in ticks], labels


PLOT_CPU_SHARE = 0.15
"""At most this share of one core goes to drawing the plot (see :class:`PlotPacer`)."""


class PlotPacer:
    """Decides when the plot is drawn again: plotext needs 50-150 ms per drawing, which at
    the 4 Hz poll rate is half a core -- taken, on a two-core bench PC, from the engine
    process whose latency it then spoils. So the plot is redrawn no sooner than its last
    drawing time / ``share`` after that drawing started (about 1 Hz for a wide terminal);
    the number panels keep the poll rate. A forced drawing (new window or size, a replay
    step) is always due."""

    def __init__(
        self, share: float = PLOT_CPU_SHARE, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.share = share
        self.clock = clock
        self._next = -math.inf
        self.drawn = 0
        self.skipped = 0

    def due(self) -> bool:
        if self.clock() >= self._next:
            return True
        self.skipped += 1
        return False

    def force(self) -> None:
        self._next = -math.inf

    def drew(self, started: float, seconds: float) -> None:
        self.drawn += 1
        self._next = started + seconds / self.share


@dataclass
class PlotSeries:
    """x = seconds before the newest sample (<= 0); one y array per trace, NaN = gap."""

    window_s: float
    x: np.ndarray
    y: dict[str, np.ndarray]
    span_s: float  # how much history there actually is
    lagged: tuple[np.ndarray, np.ndarray] | None = None  # the model's (x, y), its own times


def prepare_series(
    results: np.ndarray,
    window_s: float,
    max_points: int = 400,
    lagged: np.ndarray | None = None,
) -> PlotSeries:
    """Cut the last ``window_s`` of results (board time) and thin to ``max_points``;
    ``lagged`` (k, 3): the model's board time, lagged gradient and sigma, put on the same
    axis by the newest result's board time.

    Thinning keeps, per bucket, the sample with the largest final gradient change, so a
    one-sample dropout or spike still shows (plain striding would usually skip it)."""
    if len(results) == 0:
        return PlotSeries(window_s, np.zeros(0), {k: np.zeros(0) for k, _, _ in TRACES}, 0.0)
    t = results["time_s"]
    t_end = float(t[-1])
    start = int(np.searchsorted(t, t_end - window_s, side="left"))
    if start >= len(t) or t[start] > t_end:  # time went backwards (restart): use the tail
        start = max(0, len(t) - 1)
    sel = results[start:]
    n = len(sel)
    if n > max_points:
        edges = np.linspace(0, n, max_points + 1).astype(np.int64)
        g = sel["gradient"]
        dev = np.abs(np.nan_to_num(g - np.nanmedian(g) if np.isfinite(g).any() else g, nan=1e9))
        pick = np.array([a + int(np.argmax(dev[a:b])) for a, b in itertools.pairwise(edges)])
        sel = sel[pick]
    x = sel["time_s"] - t_end
    y = {
        "gradient": sel["gradient"].astype(np.float64),
        "g12": sel["slopes"][:, 0].astype(np.float64),
        "g23": sel["slopes"][:, 1].astype(np.float64),
        "g13": sel["slopes"][:, 2].astype(np.float64),
        "signed": sel["gradient_signed"].astype(np.float64),
    }
    lag = None
    if lagged is not None:
        lx = lagged[:, 0] - float(results["ticks"][-1]) * TICK_S
        keep = lx >= -window_s
        lx, ly = lx[keep], lagged[keep, 1]
        if len(lx) > max_points:
            pick = np.linspace(0, len(lx) - 1, max_points).astype(np.int64)
            lx, ly = lx[pick], ly[pick]
        lag = (lx, ly)
    return PlotSeries(window_s, x, y, t_end - float(t[start]), lag)


def render_plot(plot: Plot, series: PlotSeries | None, width: int, height: int) -> Text:
    """Draw the series with plotext into a Text of ``width`` x ``height`` cells.

    Runs in the poller thread (plotext needs ~100 ms for a few hundred points with lines, far
    too long for the UI thread at 4 Hz); ``plot`` is only ever used by that one thread."""
    plot.clear_data()
    plot.clear_figure()
    plot.theme("clear")
    plot.frame(False)  # the panel has a border already: two more rows of data instead
    plot.plotsize(max(10, width), max(4, height))
    plot._set_size(max(10, width), max(4, height))  # see textual-plotext issue #5
    window = series.window_s if series is not None else WINDOWS_S[0]
    plot.xlim(-window, 0)
    plot.xticks(*_ticks(window))
    lo, hi = y_range(series)
    if series is not None and len(series.x):
        for key, _label, color in TRACES:
            if key == "gradient" and series.lagged is not None:  # under the final gradient
                _line(plot, *series.lagged, LAGGED_TRACE[2], lo, hi)
            _line(plot, series.x, series.y[key], color, lo, hi)
    plot.ylim(lo, hi)
    plot.yticks(*y_ticks(lo, hi, max(4, height)))
    return Text.from_ansi(plot.build(), no_wrap=True)


def _line(plot: Plot, x: np.ndarray, y: np.ndarray, color: str, lo: float, hi: float) -> None:
    ok = np.isfinite(y)
    if ok.any():
        # clip (rather than drop) what is off the scale, so it shows at the edge
        ys = np.clip(y[ok], lo, hi)
        plot.plot(x[ok].tolist(), ys.tolist(), color=rgb(color), marker="braille")


def y_range(series: PlotSeries | None) -> tuple[float, float]:
    """The y scale: all of the final gradient and our estimate, and the pair traces but for
    their outliers (near level track one bad pair value can be hundreds of per mille and would
    flatten everything else), padded."""
    if series is None or len(series.x) == 0:
        return -1.0, 1.0
    keep: list[np.ndarray] = []
    for key, _label, _color in TRACES:
        y = series.y[key]
        y = y[np.isfinite(y)]
        if len(y) == 0:
            continue
        if key in ("gradient", "signed"):
            keep.append(y)
        else:
            keep.append(np.percentile(y, [5.0, 95.0]))
    if series.lagged is not None:
        lag = series.lagged[1]
        keep.append(lag[np.isfinite(lag)])
    if not keep:
        return -1.0, 1.0
    all_y = np.concatenate(keep)
    lo, hi = float(all_y.min()), float(all_y.max())
    pad = max(0.5, 0.08 * (hi - lo))
    return lo - pad, hi + pad


def _ticks(window: float) -> tuple[list[float], list[str]]:
    """Four x ticks labelled in seconds before now (the axis is 'seconds ago')."""
    ticks = [-window * k / 4 for k in (4, 3, 2, 1, 0)]
    labels = [f"{t:g} s" if t else "now" for t in ticks]
    return ticks, labels


class GradientPlot(Static):
    """Shows the plot text the poller drew, and asks for a redraw when its size changes
    (a plot drawn for another size would be cut or padded)."""

    drawn_size: tuple[int, int] = (0, 0)

    def show(self, text: Text | None, size: tuple[int, int] | None = None) -> None:
        if text is not None:
            self.update(text, layout=False)
            if size is not None:
                self.drawn_size = size

    def on_resize(self) -> None:
        size = (self.content_size.width, self.content_size.height)
        if size != self.drawn_size and hasattr(self.app, "redraw_plot"):
            self.app.redraw_plot()
