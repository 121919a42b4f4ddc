"""Typed, range-checked reading of parsed TOML, shared by the config, scenario and plan loaders.

Every failure is one :class:`ConfigError` line ``FILE: PATH: message``, PATH being the dotted
key (``channels[2].angle_deg``), so the operator sees which key of which file is wrong.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from typing import Any, TypeGuard

from devices.errors import ConfigError

_CONTROL = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ufffe\uffff]")


def printable(text: str) -> str:
    """``text`` with every character a terminal, a TOML comment or a record line cannot
    carry (control characters, a line break) written as its escape (``\\x07``)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def control_character(text: str) -> str | None:
    """The first character of ``text`` that a record cannot carry (a control character:
    XML 1.0 has no form for most of them), as ``U+0007``; None when there is none."""
    bad = _CONTROL.search(text)
    return f"U+{ord(bad.group()):04X}" if bad else None


"""Characters refused in text values (tab, newline and carriage return are fine)."""

_TYPE_NAMES = {
    bool: "boolean",
    int: "integer",
    float: "number",
    str: "string",
    list: "array",
    dict: "table",
}


def tname(v: Any) -> str:
    """The TOML name of a parsed value's type (``string``, ``array``, ``table``...)."""
    return _TYPE_NAMES.get(type(v), type(v).__name__)


def error(file: str, path: str, msg: str) -> ConfigError:
    return ConfigError(f"{file}: {path}: {msg}")


def is_number(v: Any) -> bool:
    """An integer or a float (a TOML boolean is neither)."""
    return not isinstance(v, bool) and isinstance(v, int | float)


def to_float(v: float) -> float:
    """float(v), with integers too large for a float becoming an infinity (then rejected as
    not finite) instead of raising OverflowError."""
    try:
        return float(v)
    except OverflowError:
        return math.inf if v > 0 else -math.inf


def is_integer(v: object) -> TypeGuard[int]:
    return not isinstance(v, bool) and isinstance(v, int)


def range_problem(
    v: float, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False
) -> str | None:
    """What is wrong with ``v`` against ``lo <= v <= hi`` (``lo < v`` with lo_open), or None."""
    if lo is not None and (v <= lo if lo_open else v < lo):
        return f"must be {'>' if lo_open else '>='} {lo:g}, got {v!r}"
    if hi is not None and v > hi:
        return f"must be <= {hi:g}, got {v!r}"
    return None


def number_problem(
    v: float, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False
) -> str | None:
    """As :func:`range_problem`, and nan and infinities are wrong too."""
    if not math.isfinite(v):
        return f"must be finite, got {v!r}"
    return range_problem(v, lo, hi, lo_open=lo_open)


class Table:
    """Typed, range-checked access to one TOML table; :meth:`done` rejects unknown keys.

    ``where`` is the table's own path ("" for the top level); a getter's ``default`` is the
    value of an absent key.
    """

    def __init__(self, file: str, where: str, value: Any) -> None:
        self.file = file
        self.where = where
        if not isinstance(value, dict):
            raise self.error("", f"expected a table, got {tname(value)}")
        self.data: dict[str, Any] = value
        self.used: set[str] = set()

    def path(self, key: str) -> str:
        if not key:
            return self.where or "(top level)"
        return f"{self.where}.{key}" if self.where else key

    def error(self, key: str, msg: str) -> ConfigError:
        """The error for ``key`` of this table; "" is the table itself, and a dotted
        path below a top-level table is taken as it is."""
        return error(self.file, self.path(key), msg)

    def has(self, key: str) -> bool:
        return key in self.data

    def require(self, key: str, why: str) -> None:
        if key not in self.data:
            raise self.error(key, f"missing ({why})")

    def raw(self, key: str, default: Any = None) -> Any:
        self.used.add(key)
        return self.data.get(key, default)

    def check_range(
        self, key: str, v: float, lo: float | None, hi: float | None, *, lo_open: bool = False
    ) -> None:
        problem = range_problem(v, lo, hi, lo_open=lo_open)
        if problem:
            raise self.error(key, problem)

    def num(
        self,
        key: str,
        default: float | None = None,
        lo: float | None = None,
        hi: float | None = None,
        *,
        lo_open: bool = False,
    ) -> float:
        v = self.raw(key, default)
        if not is_number(v):
            raise self.error(key, f"expected a number, got {tname(v)} {v!r}")
        value = to_float(v)
        problem = number_problem(value, lo, hi, lo_open=lo_open)
        if problem:
            raise self.error(key, problem)
        return value

    def integer(
        self, key: str, default: int | None = None, lo: float | None = None, hi: float | None = None
    ) -> int:
        v = self.raw(key, default)
        if not is_integer(v):
            raise self.error(key, f"expected an integer, got {tname(v)} {v!r}")
        self.check_range(key, v, lo, hi)
        return v

    def flag(self, key: str, default: bool | None = None) -> bool:
        v = self.raw(key, default)
        if not isinstance(v, bool):
            raise self.error(key, f"expected true or false, got {tname(v)} {v!r}")
        return v

    def text(self, key: str, default: str | None = None) -> str:
        v = self.raw(key, default)
        if not isinstance(v, str):
            raise self.error(key, f"expected a string, got {tname(v)} {v!r}")
        bad = control_character(v)
        if bad:
            # they reach terminals, HTML and junit.xml, where XML 1.0 cannot carry them
            raise self.error(key, f"control character {bad} not allowed in a text value")
        return v

    def choice(self, key: str, default: Any = None, *, choices: tuple[Any, ...]) -> Any:
        v = self.raw(key, default)
        if isinstance(v, bool) or v not in choices:
            shown = ", ".join(repr(c) for c in choices)
            raise self.error(key, f"{v!r} is not one of {shown}")
        return v

    def array(self, key: str) -> list[Any]:
        """An array of tables (``[[key]]``), empty when absent."""
        v = self.raw(key, [])
        if not isinstance(v, list):
            raise self.error(key, f"expected an array of tables ([[{key}]]), got {tname(v)}")
        return v

    def done(self, allowed: Iterable[str] | None = None) -> None:
        """Reject the first key (in file order) that is not ``allowed`` (default: every key
        a getter has asked for)."""
        names = sorted(allowed if allowed is not None else self.used)
        for key in self.data:
            if key not in names:
                raise self.error(key, f"unknown key (expected one of: {', '.join(names)})")
