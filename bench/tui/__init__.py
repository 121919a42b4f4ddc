"""The bench TUI (Textual): live per-pair values, votes, gradient plot, board, events, recording.

``bench tui`` / ``bench demo`` build a :class:`bench.live.session.Session` (runner, source,
recorder, replay controls) and run :class:`bench.tui.app.BenchApp` on it; see docs/TUI.md.
"""
