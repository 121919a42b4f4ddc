"""The bench TUI: a thin App that lays out the panels and maps keys to session actions.

The App never blocks on acquisition: a timer (4 Hz) starts a worker thread that copies a
:class:`~bench.live.view.Snapshot` from the session and draws the plot, then posts both back. At
most one snapshot is in flight, so a slow terminal only lowers the display rate and never
backs up the receive path (the runner's bounded queue and drop counters are shown).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import signal
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from rich.text import Text
from textual import work
from textual.app import App, ComposeResult, SystemCommand
from textual.binding import Binding, BindingType
from textual.containers import Horizontal, Vertical
from textual.css.query import NoMatches
from textual.screen import Screen
from textual.widgets import Footer, Static

from bench.errors import BenchError
from bench.live.view import HISTORY, SessionLike, Snapshot
from bench.records.results import UNIX_TIME_FROM
from bench.replay.player import ReplayStatus, speed_label
from bench.tui.help import HelpScreen
from bench.tui.messages import SessionStopped, SnapshotReady
from bench.tui.panels import duration_text
from bench.tui.panels.board import BoardPanel
from bench.tui.panels.channels import ChannelsPanel, RateMeter
from bench.tui.panels.events import EventsPanel, MarksPanel, kind_name
from bench.tui.panels.model import ModelPanel
from bench.tui.panels.pairs import PairsPanel
from bench.tui.panels.plot import (
    WINDOWS_S,
    GradientPlot,
    Plot,
    PlotPacer,
    legend_markup,
    prepare_series,
    render_plot,
)
from bench.tui.panels.recording import RecordingPanel

TOLERANCE_STEPS = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
"""What + and - step through (per mille): fine where the vote is touchy, coarse above."""

WIDE_COLUMNS = 140
MIN_SIZE = (100, 30)
"""Below this the panels would be cropped: the screen says so instead."""
QUIT_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
"""Signals that quit like ``q`` (the log is finished): kill and systemd, a closed terminal."""
REPLAY_ACTIONS = {"play_pause", "speed", "step", "next_failure"}
KEY_HELP = {
    "quit": "quit: stop, finish the MCAP log, leave",
    "pause_display": "freeze the panels (acquisition and logging go on)",
    "record": "recording off / on (a new MCAP file each time)",
    "mark": "operator mark, into the log and the Marks list",
    "tolerance": "vote tolerance up / down the ladder",
    "window": "plot window 10 s / 30 s / 1 min / 5 min",
    "filter_events": "Events: one kind only, cycling through the kinds seen; all",
    "help": "this help",
    "play_pause": "replay: play / pause",
    "speed": "replay speed 1x / 10x / max",
    "step": "replay: one sample on",
    "next_failure": "replay: run to the next event of the target (t), pause there",
    "seek_target": "replay: what j runs to: vote failure, INVALID, exclusion, fault, mark",
    "seek_back": "replay: back 10 s of log time (computed again from the start)",
    "restart": "replay: play the log again from the start",
}
"""What the help screen says for each action (the footer's labels are kept short)."""
SCREENSHOT_DIR = Path("logs")
"""Where the palette's Screenshot saves its SVG (beside the run's logs, not ~/Downloads)."""


def plot_size(plot: Text) -> tuple[int, int]:
    """(width, height) a drawn plot fills."""
    lines = plot.plain.split("\n")
    return (max((len(line) for line in lines), default=0), len(lines))


def next_tolerance(current: float, direction: int) -> float:
    if direction > 0:
        return next((s for s in TOLERANCE_STEPS if s > current + 1e-9), TOLERANCE_STEPS[-1])
    return next((s for s in reversed(TOLERANCE_STEPS) if s < current - 1e-9), TOLERANCE_STEPS[0])


class BenchApp(App[int]):
    """Live or replay view of one session (anything :class:`SessionLike`)."""

    CSS_PATH = "bench.tcss"
    TITLE = "ACB-3 bench"
    ENABLE_COMMAND_PALETTE = True

    BINDINGS: ClassVar[list[BindingType]] = [
        Binding("q", "quit", "Quit"),
        Binding("ctrl+c", "quit", "Quit", show=False, priority=True),
        Binding("p", "pause_display", "Pause display"),
        Binding("r", "record", "Rec"),
        Binding("m", "mark", "Mark"),
        Binding("plus,equals_sign", "tolerance(1)", "Tol+", key_display="+"),
        Binding("minus", "tolerance(-1)", "Tol-", key_display="-"),
        Binding("w", "window", "Window"),
        Binding("f", "filter_events", "Filter"),
        Binding("question_mark", "help", "Help", key_display="?"),
        Binding("escape", "escape", "Close", show=False),
    ]
    """The live keys; :class:`bench.tui.replay_app.ReplayApp` adds the replay keys."""

    def __init__(
        self,
        session: SessionLike,
        *,
        poll_hz: float = 4.0,
        window_s: float = 10.0,
        handle_signals: bool = False,
        notices: Sequence[str] = (),
    ) -> None:
        super().__init__()
        self.notices = list(notices)  # shown when the screen comes up (the calibration)
        self.handle_signals = handle_signals
        self.hung_up = False
        self.early_signals: list[int] = []  # received before the screen could act on them
        self.session = session
        self.poll_hz = poll_hz
        self.window_s = window_s
        self.display_paused = False
        self.cursor_n: int | None = None  # replay: the sample shown instead of the newest
        self.last_snapshot: Snapshot | None = None
        self.snapshots_applied = 0  # shown on screen
        self.snapshots_received = 0  # taken from the runner (also while the display is paused)
        self.quitting = False
        self._polling = False
        self._rates = RateMeter()
        self._plot = Plot()
        self._plot_lock = threading.Lock()
        self.plot_pacer = PlotPacer()
        self._failure_seen: object = None
        self.stop_error: str | None = None
        self.marks = 0  # operator marks (the runner also counts tolerance changes as marks)
        self.seek_label = "vote failure"  # what a replay's seek runs to (status bar)
        self.lag_s: float | None = None  # the live model's lag, once a snapshot has it

    # -- layout ---------------------------------------------------------------------------
    def compose(self) -> ComposeResult:
        yield Static(id="status-bar")
        yield Static(id="too-small")
        with Horizontal(id="top"):
            yield PairsPanel(id="pairs", classes="panel")
            yield ChannelsPanel(id="channels", classes="panel")
        with Horizontal(id="middle"):
            yield GradientPlot(id="plot", classes="panel")
            yield BoardPanel(id="board", classes="panel")
        with Horizontal(id="bottom"):
            marks = MarksPanel(id="marks", classes="panel")
            yield EventsPanel(marks, id="events", classes="panel")
            with Vertical(id="side"):
                yield RecordingPanel(id="recording", classes="panel")
                yield ModelPanel(id="model", classes="panel")
                yield marks
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.query_one("#plot").border_title = self._plot_title()
        self.query_one("#plot").border_subtitle = "w: window"
        if self.session.mode == "replay":
            self._set_clock("log time")  # UTC or run time once the first frames say which
        self.on_resize()
        self._update_status_bar()
        for line in self.notices:
            self.notify(line, timeout=20)
        if self.poll_hz > 0:
            self.set_interval(1.0 / self.poll_hz, self.poll)
            self.poll()
        if self.handle_signals:
            self._install_signal_handlers()

    def _install_signal_handlers(self) -> None:
        """SIGTERM, and SIGHUP when the terminal window is closed, quit like q: the MCAP file
        is finished instead of being cut off mid-chunk."""
        loop = asyncio.get_running_loop()
        for sig in QUIT_SIGNALS:
            with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                loop.add_signal_handler(sig, self._on_signal, sig)
        if self.early_signals:  # one came while the screen was being built
            self._on_signal(self.early_signals[0])

    def hold_signals(self) -> dict[int, Any]:
        """Until the screen is up, keep SIGTERM and SIGHUP for it: the run (and its log) may
        start before the screen does, and a signal in between would otherwise end the process
        at once, or be lost where it is inherited as ignored (under ``nohup``). Returns the
        handlers it replaced."""

        def keep(signum: int, frame: Any) -> None:
            self.early_signals.append(signum)

        return {sig: signal.signal(sig, keep) for sig in QUIT_SIGNALS}

    def _on_signal(self, sig: int) -> None:
        self.hung_up = self.hung_up or sig == signal.SIGHUP
        self.call_later(self.action_quit)

    def on_resize(self) -> None:
        """Wide terminals: let the per-pair panel and the plot share the width evenly.
        Below :data:`MIN_SIZE` the panels give way to a line saying so (cropped panels
        would show wrong-looking figures)."""
        width, height = self.size
        self.screen.set_class(width >= WIDE_COLUMNS, "-wide")
        small = width < MIN_SIZE[0] or height < MIN_SIZE[1]
        with contextlib.suppress(NoMatches):
            if small:
                self.query_one("#too-small", Static).update(
                    f"The terminal is too small: {width}x{height}.\n"
                    f"The bench screen needs at least {MIN_SIZE[0]}x{MIN_SIZE[1]};"
                    " enlarge the window (acquisition and logging go on).\n\nq quits."
                )
        self.screen.set_class(small, "-small")

    # -- snapshots ------------------------------------------------------------------------
    def poll(self) -> None:
        """Timer tick: start a snapshot worker unless one is still in flight."""
        if self._polling or self.quitting:
            return
        try:
            size = self.query_one(GradientPlot).content_size
        except NoMatches:  # the screen is being torn down
            return
        self._polling = True
        self._take_snapshot(size.width, size.height)

    @work(thread=True, exclusive=False, group="poll", exit_on_error=False)
    def _take_snapshot(self, width: int, height: int) -> None:
        session = self.session
        try:
            snap = session.snapshot(last=self._rows_needed())
            plot, rates = self._prepare(snap, width, height)
        except Exception as exc:  # shown, never fatal: the runner keeps logging regardless
            self._polling = False
            self.call_from_thread(self.notify, f"snapshot failed: {exc!r}", severity="error")
            return
        self.post_message(SnapshotReady(snap, plot, rates, session))

    def _prepare(
        self, snap: Snapshot, width: int, height: int, *, rates: bool = True, force: bool = False
    ) -> tuple[Text | None, list[float]]:
        """The heavy part of a display update: thin the series and draw the plot -- when the
        pacer says it is due (None: keep the plot on screen)."""
        rate_values = self._rates.update(snap.stats, snap.wall) if rates else []
        pacer = self.plot_pacer
        if not (force or pacer.due()):
            return None, rate_values
        lagged = snap.model.lagged if snap.model is not None else None
        series = prepare_series(
            snap.results, self.window_s, max_points=max(50, 2 * width), lagged=lagged
        )
        with self._plot_lock:
            started = pacer.clock()
            plot = render_plot(self._plot, series, width, height)
            pacer.drew(started, pacer.clock() - started)
        return plot, rate_values

    def _rows_needed(self) -> int:
        rate = self.session.sample_rate_hz
        last = self.last_snapshot
        if last is not None and last.board is not None and int(last.board["sample_rate"]) > 0:
            rate = int(last.board["sample_rate"])
        return int(min(HISTORY, self.window_s * rate * 1.1 + 100))

    def on_snapshot_ready(self, message: SnapshotReady) -> None:
        self._polling = False
        if message.source is not None and message.source is not self.session:
            return  # taken from a session a replay restart has replaced
        self.snapshots_received += 1
        self.last_snapshot = message.snapshot
        try:
            self._follow_replay(message.snapshot)
            if not self.display_paused:
                self._apply(message.snapshot, message.plot, message.rates)
            self._update_status_bar()
        except NoMatches:  # a snapshot that arrives while the screen is being torn down
            pass

    def apply_snapshot(self, snap: Snapshot) -> None:
        """Show a snapshot now, on the UI thread (tests, and fixed-snapshot sessions)."""
        self.last_snapshot = snap
        size = self.query_one(GradientPlot).content_size
        plot, rates = self._prepare(snap, size.width, size.height, force=True)
        self._apply(snap, plot, rates)
        self._update_status_bar()

    def _apply(self, snap: Snapshot, plot: Text | None, rates: list[float]) -> None:
        if not self.is_running or (self.quitting and not snap.running):
            return
        row = self._row(snap)
        self.query_one(PairsPanel).show(
            row,
            snap.tolerance_permil,
            cursor=self.cursor_n is not None,
            rows=snap.results,
            preparing=snap.warmup,
        )
        self.query_one(ChannelsPanel).show(row, snap.stats, rates)
        self.query_one(GradientPlot).show(plot, plot_size(plot) if plot is not None else None)
        self.query_one(BoardPanel).show(snap, live=self.session.mode == "live")
        extra = snap.extra
        self.query_one(RecordingPanel).show(
            snap.recording, extra.get("last_recording"), extra.get("foxglove"), snap.warmup
        )
        self.query_one(EventsPanel).show(snap.events)
        self.query_one(ModelPanel).show(snap.model)
        lag = snap.model.lag_s if snap.model is not None else None
        if lag != self.lag_s:  # the plot's legend names the lagged line
            self.lag_s = lag
            self.query_one("#plot").border_title = self._plot_title()
        self.snapshots_applied += 1

    def redraw_plot(self) -> None:
        """The plot panel changed size: draw the last snapshot again for the new size."""
        snap = self.last_snapshot
        widget = self.query_one(GradientPlot)
        size = widget.content_size
        if snap is None or size.width <= 0 or size.height <= 0 or self.display_paused:
            return
        plot, _ = self._prepare(snap, size.width, size.height, rates=False, force=True)
        if plot is not None:
            widget.show(plot, plot_size(plot))

    def _row(self, snap: Snapshot) -> np.void | None:
        res = snap.results
        if len(res) == 0:
            return None
        if self.cursor_n is not None:
            hit = np.flatnonzero(res["n"] == self.cursor_n)
            if len(hit):
                return res[int(hit[0])]
        return res[-1]

    def _set_clock(self, clock: str) -> None:
        for table in self.query(EventsPanel), self.query(MarksPanel):
            for widget in table:
                widget.set_clock(clock)

    def _follow_replay(self, snap: Snapshot) -> None:
        rs: ReplayStatus | None = snap.extra.get("replay")
        if rs is not None and math.isfinite(rs.log_t0):
            # an emulator's log counts from its start: its times are run time, not UTC
            self._set_clock("log time, UTC" if rs.log_t0 >= UNIX_TIME_FROM else "run time")
        if rs is None or rs.failure is None or rs.failure is self._failure_seen:
            return
        self._failure_seen = rs.failure
        self.cursor_n = rs.failure.n
        self.notify(f"stopped at {rs.failure.text}", title=self.seek_label)

    # -- status bar -----------------------------------------------------------------------
    def _update_status_bar(self) -> None:
        s = self.last_snapshot
        text = Text()
        text.append(" ACB-3 bench ", style="bold reverse")
        rs: ReplayStatus | None = s.extra.get("replay") if s is not None else None
        if self.session.mode == "replay":
            text.append(" REPLAY ", style="bold black on cyan")
            if rs is not None:
                if rs.seeking:
                    state = f"⏩ seeking {self.seek_label}"
                    if math.isfinite(rs.seek_fraction):
                        state += f" {100 * rs.seek_fraction:.0f}%"
                elif rs.finished and rs.consumed >= rs.emitted:
                    state = "■ end of log"
                else:
                    state = "⏸ paused" if rs.paused else "▶ playing"
                text.append(f" {state} {speed_label(rs.speed)}")
                if math.isfinite(rs.fraction):
                    text.append(f"  {100 * rs.fraction:.0f}%")
                if math.isfinite(rs.log_t) and math.isfinite(rs.log_t0):
                    text.append(f"  log {duration_text(rs.log_t - rs.log_t0)}")
        else:
            text.append(" LIVE ", style="bold black on green")
        if self.display_paused:
            text.append(" ", style="")
            text.append(" PAUSED ", style="bold black on yellow")
        if s is not None:
            text.append(f"  {s.source}")
            if len(s.results):
                text.append(f"  t {float(s.results['time_s'][-1]):.1f} s")
            if s.warmup is not None:
                text.append(f"  {s.warmup.spinner()} estimator {s.warmup.elapsed_s:.0f} s")
            if s.extra.get("emulator_done"):
                text.append("  scenario finished", style="yellow")
            if not s.running:
                text.append("  stopped", style="yellow")
        if self.session.recorder.active:
            failed = s is not None and s.recording is not None and s.recording.error
            if failed:  # the recording panel says why; the header must not claim REC
                text.append("  ✖ LOG FAILED", style="bold white on red")
            else:
                text.append("  ● REC", style="bold red")
        if self.display_paused:
            text.append("  display paused: acquisition and log continue", style="yellow")
        if self.quitting:
            wait = " once the estimator is ready" if s is not None and s.warmup else ""
            text.append(f"  finishing the log{wait}…", style="bold yellow")
        self.query_one("#status-bar", Static).update(text, layout=False)
        self.title = f"{self.TITLE} PAUSED" if self.display_paused else self.TITLE

    def _plot_title(self) -> str:
        w = self.window_s
        span = f"{w:.0f} s" if w < 120 else f"{w / 60:.0f} min"
        return f"Gradient ‰ · last {span} · {legend_markup(self.lag_s)}"

    # -- actions --------------------------------------------------------------------------
    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        if action in REPLAY_ACTIONS:
            return self.session.replay is not None
        if action in ("record", "mark", "tolerance") and not self.session.controllable:
            return None
        return True

    def action_pause_display(self) -> None:
        """Freeze the panels; acquisition, fusion and logging go on underneath."""
        self.display_paused = not self.display_paused
        self._update_status_bar()
        if not self.display_paused and self.last_snapshot is not None:
            self.poll()

    def action_record(self) -> None:
        rec = self.session.recorder
        if rec.active:
            sink = rec.detach()
            self.notify(f"recording stopped: {getattr(sink, 'path', '')}")
            self._finish_recording(sink)
        else:
            if not rec.can_start:
                self.notify("this session cannot record", severity="warning")
                return
            try:
                path = rec.start()
            except (BenchError, OSError, RuntimeError) as exc:
                self.notify(f"cannot record: {exc}", severity="error")
                return
            self.notify(f"recording to {path}")
        self._update_status_bar()

    @work(thread=True, group="recording", exit_on_error=False)
    def _finish_recording(self, sink: object) -> None:
        """Closing an MCAP file flushes and writes its summary: not on the UI thread."""
        try:
            self.session.recorder.finish(sink)
        except Exception as exc:
            self.call_from_thread(self.notify, f"closing the log failed: {exc!r}", severity="error")

    def action_mark(self) -> None:
        self.marks += 1
        self.session.mark(f"operator mark {self.marks}")
        self.notify(f"mark {self.marks} recorded")

    def action_tolerance(self, direction: int) -> None:
        tol = next_tolerance(self.session.tolerance(), int(direction))
        self.session.set_tolerance(tol)
        self.notify(f"tolerance ±{tol:g} ‰")

    def action_filter_events(self) -> None:
        """Show only one kind of event: all -> each kind seen so far -> all."""
        kind = self.query_one(EventsPanel).cycle_filter()
        self.notify(f"events: {'all' if kind is None else kind_name(kind) + ' only'}")

    def _key_help(self) -> list[tuple[str, str]]:
        """(key, what it does) for every key of this App, footer or not."""
        by_key: dict[str, Binding] = {}
        for cls in reversed(type(self).__mro__):
            for binding in cls.__dict__.get("BINDINGS", []):
                if isinstance(binding, Binding):
                    by_key[binding.key] = binding
        out = []
        for binding in by_key.values():
            action = binding.action.split("(")[0]
            if binding.key in ("ctrl+c", "escape") or binding.action == "tolerance(-1)":
                continue  # one line for + and -; escape has its own line
            if self.check_action(action, ()) is False:
                continue
            key = binding.key_display or binding.key.split(",")[0]
            key = "+ / -" if key == "+" else key
            out.append((key, KEY_HELP.get(action, binding.description)))
        return out

    def action_help(self) -> None:
        if not isinstance(self.screen, HelpScreen):
            self.push_screen(HelpScreen(self._key_help(), replay=self.session.mode == "replay"))

    def action_escape(self) -> None:
        """Close what is open: the help or the palette (their own Escape), else leave the
        Events list, which then follows the newest rows again."""
        if isinstance(self.screen, HelpScreen):
            self.screen.dismiss(None)
            return
        if self.focused is not None:
            self.set_focus(None)
            self.query_one(EventsPanel).scroll_end(animate=False)

    def action_screenshot(self, filename: str | None = None, path: str | None = None) -> None:
        """Save an SVG of the screen under ``logs/`` (created if need be)."""
        folder = Path(path) if path else SCREENSHOT_DIR
        try:
            folder.mkdir(parents=True, exist_ok=True)
            name = filename or time.strftime("screen-%Y%m%dT%H%M%SZ.svg", time.gmtime())
            saved = self.save_screenshot(name, str(folder))
        except OSError as exc:
            self.notify(f"screenshot failed: {exc.strerror or exc}", severity="error")
            return
        self.notify(f"screenshot saved to {saved}", title="Screenshot")

    def action_window(self) -> None:
        i = WINDOWS_S.index(self.window_s) if self.window_s in WINDOWS_S else -1
        self.window_s = WINDOWS_S[(i + 1) % len(WINDOWS_S)]
        self.query_one("#plot").border_title = self._plot_title()
        self.plot_pacer.force()  # the next snapshot draws the new window

    def action_play_pause(self) -> None:
        if self.session.replay is None:
            return
        paused = self.session.replay.toggle()
        if not paused:
            self.cursor_n = None
        self._update_status_bar()

    def action_speed(self) -> None:
        if self.session.replay is not None:
            self.notify(f"replay speed {speed_label(self.session.replay.cycle_speed())}")

    def action_step(self) -> None:
        """One sample on: within what is already fused (exact), else one period of log."""
        replay = self.session.replay
        if replay is None:
            return
        snap = self.last_snapshot
        if self.cursor_n is not None and snap is not None and len(snap.results):
            later = snap.results["n"][snap.results["n"] > self.cursor_n]
            if len(later):
                self.cursor_n = int(later.min())
                self._apply_last()
                return
            self.cursor_n = None
        replay.step()

    def _apply_last(self) -> None:
        if self.last_snapshot is not None:
            self.apply_snapshot(self.last_snapshot)

    def action_next_failure(self) -> None:
        if self.session.replay is not None:
            self.cursor_n = None
            self.session.replay.seek_failure()
            self._update_status_bar()

    async def action_quit(self) -> None:
        """Stop acquisition and close the MCAP file (summary written) before leaving."""
        if self.quitting:
            return
        self.quitting = True
        self._update_status_bar()
        self._stop_session()

    @work(thread=True, group="stop", exit_on_error=False)
    def _stop_session(self) -> None:
        error: str | None = None
        try:
            self.session.stop()
            error = self.session.error
        except Exception as exc:
            error = repr(exc)
        self.post_message(SessionStopped(error))

    def on_session_stopped(self, message: SessionStopped) -> None:
        self.stop_error = message.error
        if self.hung_up:
            # The terminal is gone and Textual would wait forever to restore it; the run is
            # stopped and every log file finished, so leave now.
            os._exit(1 if message.error else 0)
        self.exit(1 if message.error else 0)

    # -- command palette ------------------------------------------------------------------
    def get_system_commands(self, screen: Screen) -> Iterable[SystemCommand]:
        yield SystemCommand("Pause display", "Freeze the panels (p)", self.action_pause_display)
        yield SystemCommand(
            "Record on/off", "Start or stop an MCAP recording (r)", self.action_record
        )
        yield SystemCommand("Mark event", "Put an operator mark into the log (m)", self.action_mark)
        yield SystemCommand(
            "Tolerance up", "Widen the vote tolerance (+)", lambda: self.action_tolerance(1)
        )
        yield SystemCommand(
            "Tolerance down", "Narrow the vote tolerance (-)", lambda: self.action_tolerance(-1)
        )
        yield SystemCommand(
            "Plot window", "Cycle 10 s / 30 s / 1 min / 5 min (w)", self.action_window
        )
        yield SystemCommand(
            "Filter events", "Show one kind of event, or all (f)", self.action_filter_events
        )
        yield SystemCommand("Help", "Keys and panels (?)", self.action_help)
        yield SystemCommand(
            "Screenshot", "Save an SVG of the screen under logs/", self.action_screenshot
        )
        yield SystemCommand("Quit", "Stop, finish the MCAP log and leave (q)", self.action_quit)
        for cmd in super().get_system_commands(screen):
            if cmd.title not in ("Quit", "Screenshot"):
                yield cmd
