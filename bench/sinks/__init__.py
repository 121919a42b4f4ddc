"""Sinks: where a step's output goes (the Sink contract, CSV, summary, queued sinks)."""
