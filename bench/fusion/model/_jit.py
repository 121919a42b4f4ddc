"""numba's njit with its type kept for mypy (numba ships no type information)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

from numba import njit

Fn = TypeVar("Fn", bound=Callable[..., Any])


def jit(fn: Fn) -> Fn:
    """Compile ``fn`` in nopython mode with numba's disk cache, releasing the GIL while it
    runs (the live model's thread then never holds up acquisition); the same signature
    for mypy."""
    return cast(Fn, njit(cache=True, nogil=True)(fn))
