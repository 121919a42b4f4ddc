"""Run the screen on a session: start it, run the App in this terminal, always stop it."""

from __future__ import annotations

import signal
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bench.live.view import SessionLike


def run_tui(session: SessionLike, **app_kwargs: Any) -> int:
    """Start the session, run the App in this terminal, and always stop the session (a live
    one runs in the engine process, :mod:`bench.engine.client`; the App cannot tell). Even a
    Ctrl-C while Textual is still being imported stops the session."""
    try:
        from bench.tui.replay_app import create_app

        app = create_app(session, handle_signals=True, **app_kwargs)
        held = app.hold_signals()  # until the screen is up; it quits on one that came
        try:
            session.start()
            code = app.run()
        finally:
            for sig, handler in held.items():
                signal.signal(sig, handler)
    finally:
        session.stop()
    return 1 if session.error else int(code or 0)
