"""The engine process's entry point, apart from its code: the screen process names it as the
multiprocessing target, and the run's modules (pipeline, fusion, MCAP writer) are imported
in the engine process alone."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bench.engine.plans import EnginePlan


def child_entry(conn: Any, plan: EnginePlan) -> None:
    """Run the engine (:func:`bench.engine.child.child_main`) in this process."""
    from bench.engine.child import child_main

    child_main(conn, plan)
