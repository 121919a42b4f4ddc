"""Fusion: the device's reference method (reference.py) and the bench's own estimator."""
