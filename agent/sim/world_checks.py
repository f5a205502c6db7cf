"""Checks on the values of world entries, shared by world files and worlds built in code.

Each check returns the value in the form the world is built from (floats, ``(x, y)`` pairs)
or raises :class:`~agent.errors.WorldFileError` with a one-line message naming the file (if
any) and the entry, e.g. ``world file w.toml: [[box]] 2: size must be two positive numbers,
got [0.4, -1]``. Entries are numbered from 1. Booleans are not numbers.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from agent.errors import WorldFileError

__all__ = ["WorldChecker", "show_value"]

_Point = tuple[float, float]  # (x, y), metres


def show_value(value: Any, limit: int = 60) -> str:
    """Render a value the way it would look in TOML, on one line, shortened to ``limit``."""

    def render(v: Any, depth: int) -> str:
        if isinstance(v, bool | np.bool_):
            return "true" if v else "false"
        if isinstance(v, int | float | np.integer | np.floating):
            return repr(v.item() if isinstance(v, np.generic) else v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, Mapping):
            return "a table {" + ", ".join(str(k) for k in v) + "}"
        if isinstance(v, list | tuple):
            if depth > 3:
                return "[...]"
            return "[" + ", ".join(render(x, depth + 1) for x in v) + "]"
        return f"a {type(v).__name__}"

    text = " ".join(render(value, 0).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _finite(value: Any) -> float | None:
    """``value`` as a finite float, or ``None`` if it is not a finite number.

    int and float (and numpy numbers) are numbers; booleans are not. Integers too large for a
    float are not finite.
    """
    if not isinstance(value, int | float | np.integer | np.floating) or isinstance(
        value, bool | np.bool_
    ):
        return None
    try:
        x = float(value)
    except OverflowError:
        return None
    return x if math.isfinite(x) else None


class WorldChecker:
    """Validation helpers that raise :class:`WorldFileError` naming ``path`` and the entry."""

    def __init__(self, path: str | Path | None) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> NoReturn:
        raise WorldFileError(self.path, f"{where}: {problem}" if where else problem)

    def finite(self, value: Any, where: str, key: str) -> float:
        x = _finite(value)
        if x is None:
            self.fail(where, f"{key} must be a finite number, got {show_value(value)}")
        return x

    def positive(self, value: Any, where: str, key: str) -> float:
        x = _finite(value)
        if x is None or not x > 0.0:
            self.fail(where, f"{key} must be a finite positive number, got {show_value(value)}")
        return x

    def _floats(self, value: Any, n: int) -> list[float] | None:
        if not isinstance(value, list | tuple) or len(value) != n:
            return None
        xs = [_finite(v) for v in value]
        return None if None in xs else [x for x in xs if x is not None]

    def numbers(self, value: Any, n: int, where: str, key: str, what: str) -> tuple[float, ...]:
        """``value`` as ``n`` finite floats; ``what`` describes the expected form."""
        xs = self._floats(value, n)
        if xs is None:
            label = f"{key} must be" if key else "must be"
            count = {2: "two", 3: "three"}.get(n, str(n))
            self.fail(where, f"{label} {count} finite numbers {what}, got {show_value(value)}")
        return tuple(xs)

    def point(self, value: Any, where: str, key: str) -> _Point:
        x, y = self.numbers(value, 2, where, key, "[x, y]")
        return (x, y)

    def positive_pair(self, value: Any, where: str, key: str) -> _Point:
        xs = self._floats(value, 2)
        if xs is None or not (xs[0] > 0.0 and xs[1] > 0.0):
            self.fail(where, f"{key} must be two positive numbers, got {show_value(value)}")
        return (xs[0], xs[1])

    def polyline(self, value: Any, where: str) -> tuple[_Point, ...]:
        if not isinstance(value, list | tuple):
            self.fail(where, f"points must be a list of [x, y] pairs, got {show_value(value)}")
        if len(value) < 2:
            self.fail(where, f"points must hold at least 2 points, got {len(value)}")
        pts = tuple(self.point(p, where, f"point {j + 1} of points") for j, p in enumerate(value))
        for j in range(len(pts) - 1):
            if pts[j] == pts[j + 1]:
                self.fail(
                    where,
                    f"zero-length segment: points {j + 1} and {j + 2} are both "
                    f"{show_value(list(pts[j]))}",
                )
        return pts

    def table(self, value: Any, where: str, allowed: tuple[str, ...]) -> Mapping[str, Any]:
        """``value`` as a table with keys from ``allowed`` only."""
        if not isinstance(value, Mapping):
            self.fail(where, f"must be a table, got {show_value(value)}")
        for key in value:
            if key not in allowed:
                self.fail(
                    where,
                    f"unknown key {show_value(key)}; allowed keys: {', '.join(allowed)}",
                )
        return value
