"""Acceptance check kinds: one module per family, a registry of them by name (registry.py)."""
