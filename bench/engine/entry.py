"""The engine process's entry point, apart from its code: the screen process starts
``python -m bench.engine.entry`` (:func:`devices.child_process.start_child`) and the run's
modules (pipeline, fusion, MCAP writer) are imported in the engine process alone."""

from __future__ import annotations

import sys


def main() -> None:
    """Take the plan from the parent (the connection's first message) and run the engine."""
    from bench.engine.child import child_main
    from devices.child_process import parent_connection

    conn = parent_connection(sys.argv)
    try:
        plan = conn.recv()
    except (EOFError, OSError):  # the parent went away before it sent the plan
        return
    child_main(conn, plan)


if __name__ == "__main__":
    main()
