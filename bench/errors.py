"""The operator-facing errors, under the bench's name (defined in devices.errors, the lowest
layer that raises them, so that devices/ never imports bench/)."""

from devices.errors import BenchError, ConfigError

__all__ = ["BenchError", "ConfigError"]
