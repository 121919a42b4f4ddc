"""Replaying recorded logs through the pipeline as fast as possible."""
