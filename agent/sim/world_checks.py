"""Checks on the values of world entries, shared by world files and worlds built in code.

Each check returns the value in the form the world is built from (floats, ``(x, y)`` pairs)
or raises :class:`~agent.errors.WorldFileError` with a one-line message naming the file (if
any) and the entry, e.g. ``world file w.toml: [[box]] 2: size must be two positive numbers,
got [0.4, -1]``. Entries are numbered from 1. Booleans are not numbers.

World files, which come from outside the program, are also held to these limits (worlds
built in code are trusted with any finite geometry):

* at most :data:`MAX_OBSTACLES` (10 000) obstacles: a building floor drawn in detail has
  hundreds, and ray casting slows with the count;
* at most :data:`MAX_WALL_POINTS` (128) points in one wall and :data:`MAX_TOTAL_WALL_POINTS`
  (65 536) in all walls: a room traced from a plan needs tens, a longer outline can be split
  into several walls, and together they bound the test that no wall meets itself, over every
  pair of a wall's segments, to about four million pairs (a thousand walls of 64 points make
  two million);
* every x and y within :data:`MAX_COORDINATE_M` (1000 m) of the origin: a site a vehicle drives
  over, where float64 still resolves 1e-13 m (the sensor reaches 2.5 m);
* box sides, cylinder radii and wall segments from :data:`MIN_SIZE_M` (1 mm) to
  :data:`MAX_SIZE_M` (1000 m; segments have no upper bound but their ends'): a sweep samples
  every 40°/256 = 2.7 mrad, 1.1 mm apart even at the nearest range of 0.4 m, so anything
  smaller can fall between samples, and is a degenerate shape to the ray caster;
* reflectivity in (0, :data:`MAX_REFLECTIVITY`] (1000), relative to off-white cardboard:
  retroreflective sheeting, the brightest surface about, returns some hundreds of times more
  light toward the source than a white diffuse one;
* angles (``*_deg``) within ±:data:`MAX_ANGLE_DEG` (360°): one turn either way; larger values
  are typing errors and lose precision in sine and cosine;
* a name of one line and at most :data:`MAX_NAME_CHARS` (256) characters;
* at most :data:`MAX_MOVERS` (64) movers, each with a path of 2 to :data:`MAX_MOVER_POINTS`
  (128) points: every beam of the simulator is tested against every mover (they cannot be
  culled by place, since they move), so their count bounds a sweep's cost; a crowd of people
  about a vehicle is tens;
* a mover's speed from 0 to :data:`MAX_MOVER_SPEED_M_S` (3 m/s, a run; the vehicle drives at
  0.5 m/s), its radius as a cylinder's, its path's points as a wall's (within 1000 m, no two
  neighbours equal), and a path of zero length (every point the same) only at speed 0.

A world file's ``[task]`` (:mod:`agent.task`) names its ``kind`` (``"goto"``, ``"park"`` or
``"dock"``) and ``goal`` (a point, within the limit on coordinates); ``goal_yaw_deg`` is
required for ``park`` and refused for the others (within ±360°), ``dock_distance_m`` refused
but for ``dock``; ``tolerance_m``, ``tolerance_deg`` (at most 180°: no heading is further off),
``time_limit_s`` and ``dock_distance_m`` are finite and positive.

A wall must also be a simple polyline: segment ``j`` joins points ``j`` and ``j + 1``;
segments that are not neighbours must not meet (cross or touch), and neighbours must not turn
back along each other. A wall whose last point repeats its first is closed (a polygon, such as
a room), and its first and last segments are neighbours.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import numpy.typing as npt

from agent.errors import WorldFileError
from agent.task import TASK_KINDS, Task

__all__ = [
    "MAX_ANGLE_DEG",
    "MAX_COORDINATE_M",
    "MAX_MOVERS",
    "MAX_MOVER_POINTS",
    "MAX_MOVER_SPEED_M_S",
    "MAX_NAME_CHARS",
    "MAX_OBSTACLES",
    "MAX_REFLECTIVITY",
    "MAX_SIZE_M",
    "MAX_TOLERANCE_DEG",
    "MAX_TOTAL_WALL_POINTS",
    "MAX_WALL_POINTS",
    "MIN_SIZE_M",
    "TASK_KEYS",
    "WorldChecker",
    "first_wall_contact",
    "show_value",
]

_Point = tuple[float, float]  # (x, y), metres

MAX_OBSTACLES = 10_000
"""Most obstacles (walls, boxes and cylinders together) in a world file."""
MAX_WALL_POINTS = 128
"""Most points in one wall of a world file."""
MAX_TOTAL_WALL_POINTS = 65_536
"""Most points in all the walls of a world file together."""
MAX_COORDINATE_M = 1000.0
"""Largest magnitude of any x or y in a world file, metres."""
MIN_SIZE_M = 1e-3
"""Smallest box side, cylinder radius and wall segment in a world file, metres."""
MAX_SIZE_M = 1000.0
"""Largest box side and cylinder radius in a world file, metres."""
MAX_REFLECTIVITY = 1000.0
"""Largest reflectivity in a world file, relative to off-white cardboard (1.0)."""
MAX_ANGLE_DEG = 360.0
"""Largest magnitude of an angle in a world file, degrees."""
MAX_NAME_CHARS = 256
"""Longest world name in a world file, characters."""
MAX_MOVERS = 64
"""Most movers in a world file."""
MAX_MOVER_POINTS = 128
"""Most points in one mover's path."""
MAX_MOVER_SPEED_M_S = 3.0
"""Fastest mover in a world file, m/s."""
MAX_TOLERANCE_DEG = 180.0
"""Largest heading tolerance of a task, degrees: no heading is further off than this."""
TASK_KEYS = (
    "kind", "goal", "goal_yaw_deg", "tolerance_m", "tolerance_deg", "time_limit_s",
    "dock_distance_m",
)  # fmt: skip
"""The keys of a world file's ``[task]`` (an interface: other tools write them)."""
_TASK_DEFAULTS = Task("dock", (0.0, 0.0))  # defaults of the optional keys

_PAIRS_PER_CHUNK = 1 << 17
"""Pairs of segments tested at once by :func:`first_wall_contact` (about 1 MB per array)."""
_FOLD_TOLERANCE = 1e-9
"""Neighbouring segments whose directions differ from opposite by less than this (radians,
as a sine) turn back along each other: a spike of no area."""


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


def _plain_points(value: list[Any] | tuple[Any, ...]) -> npt.NDArray[np.float64] | None:
    """``value`` as (p, 2) finite floats if it is a list of [x, y] pairs of plain ints and
    floats (what TOML gives), else ``None``: a fast path for walls of many points."""
    plain = (int, float)  # compared by exact type: no booleans, no numpy numbers
    if not all(
        type(p) in (list, tuple) and len(p) == 2 and type(p[0]) in plain and type(p[1]) in plain
        for p in value
    ):
        return None
    try:
        arr = np.array(value, dtype=np.float64)
    except OverflowError:  # an integer too large for a float
        return None
    return arr if bool(np.isfinite(arr).all()) else None


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
        return tuple((x, y) for x, y in self._polyline(value, where).tolist())

    def _polyline(self, value: Any, where: str) -> npt.NDArray[np.float64]:
        """``value`` as (p, 2) floats, p >= 2, with no two neighbours equal."""
        if not isinstance(value, list | tuple):
            self.fail(where, f"points must be a list of [x, y] pairs, got {show_value(value)}")
        if len(value) < 2:
            self.fail(where, f"points must hold at least 2 points, got {len(value)}")
        arr = _plain_points(value)
        if arr is None:  # something is wrong: find it, point by point, to name it
            arr = np.array(
                [self.point(p, where, f"point {j + 1} of points") for j, p in enumerate(value)]
            )
        repeated = np.flatnonzero(np.all(arr[1:] == arr[:-1], axis=1))
        if repeated.size:
            j = int(repeated[0])
            self.fail(
                where,
                f"zero-length segment: points {j + 1} and {j + 2} are both "
                f"{show_value(arr[j].tolist())}",
            )
        return arr

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

    # ----------------------------------------------------------------------------------------
    # The limits a world file is held to (see the module docstring)
    # ----------------------------------------------------------------------------------------

    def count(self, n: int, limit: int, where: str, what: str) -> None:
        """Refuse more than ``limit`` of ``what``."""
        if n > limit:
            self.fail(where, f"{n} {what} is more than the limit of {limit}")

    def coordinates(self, xy: Sequence[float], where: str, key: str) -> None:
        """Refuse any x or y farther than :data:`MAX_COORDINATE_M` from the origin."""
        if any(abs(v) > MAX_COORDINATE_M for v in xy):
            self.fail(
                where,
                f"{key} must lie within {MAX_COORDINATE_M:g} m of the origin in x and y, "
                f"got {show_value(list(xy))}",
            )

    def size(self, x: float, where: str, key: str) -> None:
        """Refuse a box side or radius outside [:data:`MIN_SIZE_M`, :data:`MAX_SIZE_M`]."""
        if not MIN_SIZE_M <= x <= MAX_SIZE_M:
            self.fail(
                where,
                f"{key} must be from {MIN_SIZE_M * 1e3:g} mm to {MAX_SIZE_M:g} m, got {x!r}",
            )

    def reflectivity(self, x: float, where: str) -> None:
        """Refuse a reflectivity above :data:`MAX_REFLECTIVITY` (it is already > 0)."""
        if x > MAX_REFLECTIVITY:
            self.fail(
                where,
                f"reflectivity must be at most {MAX_REFLECTIVITY:g} (relative to off-white "
                f"cardboard), got {x!r}",
            )

    def angle_deg(self, x: float, where: str, key: str) -> None:
        """Refuse an angle beyond ±:data:`MAX_ANGLE_DEG`."""
        if abs(x) > MAX_ANGLE_DEG:
            self.fail(where, f"{key} must be within ±{MAX_ANGLE_DEG:g} deg, got {x!r}")

    def name(self, value: str) -> None:
        """Refuse a name longer than :data:`MAX_NAME_CHARS` or of more than one line."""
        if len(value) > MAX_NAME_CHARS or len(value.splitlines()) > 1:
            self.fail(
                "",
                f"name must be one line of at most {MAX_NAME_CHARS} characters, "
                f"got {show_value(value)}",
            )

    def wall(self, value: Any, where: str) -> npt.NDArray[np.float64]:
        """A world file's wall: a polyline (p, 2), metres, whose points lie within
        :data:`MAX_COORDINATE_M` of the origin and whose segments are at least
        :data:`MIN_SIZE_M` long (see :func:`first_wall_contact` for the test that it does not
        meet itself, done for all walls at once)."""
        pts = self._polyline(value, where)
        far = np.flatnonzero(np.any(np.abs(pts) > MAX_COORDINATE_M, axis=1))
        if far.size:
            j = int(far[0])
            self.coordinates(pts[j].tolist(), where, f"point {j + 1} of points")
        lengths = np.hypot(*np.diff(pts, axis=0).T)
        short = np.flatnonzero(lengths < MIN_SIZE_M)
        if short.size:
            j = int(short[0])
            self.fail(
                where,
                f"segment {j + 1} (points {j + 1} to {j + 2}) is {lengths[j]:.3g} m long, "
                f"shorter than {MIN_SIZE_M * 1e3:g} mm",
            )
        return pts

    def task(self, value: Any) -> Task:
        """A world file's ``[task]`` table as a :class:`~agent.task.Task` (radians inside)."""
        where = "[task]"
        table = self.table(value, where, TASK_KEYS)
        for key in ("kind", "goal"):
            if key not in table:
                self.fail(where, f"missing key {show_value(key)}")
        kind = table["kind"]
        if not isinstance(kind, str) or kind not in TASK_KINDS:
            choices = ", ".join(show_value(k) for k in TASK_KINDS)
            self.fail(where, f"kind must be one of {choices}, got {show_value(kind)}")
        goal = self.point(table["goal"], where, "goal")
        self.coordinates(goal, where, "goal")
        for key, only in (("goal_yaw_deg", "park"), ("dock_distance_m", "dock")):
            if key in table and kind != only:
                self.fail(
                    where, f"{key} is for kind {show_value(only)} only, not {show_value(kind)}"
                )
        goal_yaw_rad = None
        if kind == "park":
            if "goal_yaw_deg" not in table:
                self.fail(where, 'missing key "goal_yaw_deg" (required for kind "park")')
            yaw_deg = self.finite(table["goal_yaw_deg"], where, "goal_yaw_deg")
            self.angle_deg(yaw_deg, where, "goal_yaw_deg")
            goal_yaw_rad = math.radians(yaw_deg)
        d = _TASK_DEFAULTS

        def positive(key: str, default: float) -> float:
            return self.positive(table.get(key, default), where, key)

        tolerance_rad = d.tolerance_rad
        if "tolerance_deg" in table:
            tolerance_deg = positive("tolerance_deg", 0.0)
            if tolerance_deg > MAX_TOLERANCE_DEG:
                self.fail(
                    where,
                    f"tolerance_deg must be at most {MAX_TOLERANCE_DEG:g}, got {tolerance_deg!r}",
                )
            tolerance_rad = math.radians(tolerance_deg)
        return Task(
            kind=kind,
            goal=goal,
            goal_yaw_rad=goal_yaw_rad,
            tolerance_m=positive("tolerance_m", d.tolerance_m),
            tolerance_rad=tolerance_rad,
            time_limit_s=positive("time_limit_s", d.time_limit_s),
            dock_distance_m=positive("dock_distance_m", d.dock_distance_m),
        )

    def mover(
        self, value: Mapping[str, Any], where: str, file_limits: bool
    ) -> tuple[npt.NDArray[np.float64], float, float]:
        """A mover's ``path`` (p, 2), ``radius`` and ``speed`` from its table (``reflectivity``
        is checked by the caller); ``file_limits`` adds the limits held to world files."""
        radius = self.positive(value["radius"], where, "radius")
        speed = self.finite(value["speed"], where, "speed")
        if not 0.0 <= speed <= MAX_MOVER_SPEED_M_S:
            self.fail(where, f"speed must be from 0 to {MAX_MOVER_SPEED_M_S:g} m/s, got {speed!r}")
        raw = value["path"]
        if not isinstance(raw, list | tuple):
            self.fail(where, f"path must be a list of [x, y] pairs, got {show_value(raw)}")
        if file_limits:
            self.size(radius, where, "radius")
            self.count(len(raw), MAX_MOVER_POINTS, where, "points in path")
        if len(raw) < 2:
            self.fail(where, f"path must hold at least 2 points, got {len(raw)}")
        pts = _plain_points(raw)
        if pts is None:
            pts = np.array(
                [self.point(p, where, f"point {j + 1} of path") for j, p in enumerate(raw)]
            )
        if file_limits:
            far = np.flatnonzero(np.any(np.abs(pts) > MAX_COORDINATE_M, axis=1))
            if far.size:
                j = int(far[0])
                self.coordinates(pts[j].tolist(), where, f"point {j + 1} of path")
        same = np.all(pts[1:] == pts[:-1], axis=1)
        if same.all():
            if speed != 0.0:
                self.fail(
                    where,
                    f"path has zero length (every point is the same) but speed is "
                    f"{speed!r}: a mover that stands still needs speed 0",
                )
        elif same.any():
            j = int(np.flatnonzero(same)[0])
            self.fail(
                where,
                f"path points {j + 1} and {j + 2} are both {show_value(pts[j].tolist())}",
            )
        return pts, radius, speed


def first_wall_contact(walls: Sequence[npt.ArrayLike]) -> tuple[int, int, int, str] | None:
    """Find the first wall that meets itself.

    Parameters
    ----------
    walls
        Polylines, each (p, 2) or ((x, y), ...) metres, of at least 2 points with no two neighbours
        equal. Segment ``j`` joins points ``j`` and ``j + 1``; a wall whose last point equals
        its first is closed, and then its first and last segments are neighbours too.

    Returns
    -------
    (wall, i, j, how) or None
        The first wall (numbered from 0) with two segments ``i < j`` (from 0; the first such
        pair in that order) that meet: ``how`` is ``"cross"`` when each passes through the
        other, ``"touch"`` when they meet otherwise, and ``"turn back on each other"`` for
        neighbours that run back along each other. ``None`` if every wall is simple.

    Notes
    -----
    Walls with the same number of points are tested together, all pairs of their segments at
    once, in chunks of at most ``_PAIRS_PER_CHUNK`` pairs: a thousand walls of 64 points take a
    few dozen array operations on each of 16 chunks, not a loop over two million pairs.
    Orientations are the signs of cross products in float64: exact for coordinates that are
    whole numbers (or any small multiples of one power of two), right up to rounding otherwise.
    """
    by_points: dict[int, list[int]] = {}
    for w, wall in enumerate(walls):
        n_points = np.shape(wall)[0]
        if n_points >= 3:  # a single segment cannot meet itself
            by_points.setdefault(n_points, []).append(w)
    found: list[tuple[int, int, int, str]] = []
    for n_points, members in by_points.items():
        n_seg = n_points - 1
        i, j = np.triu_indices(n_seg, k=2)  # pairs that are not neighbours in an open wall
        closing = (i == 0) & (j == n_seg - 1)  # ... but are in a closed one
        per_chunk = max(1, _PAIRS_PER_CHUNK // max(i.size, 1))
        for start in range(0, len(members), per_chunk):
            chunk = members[start : start + per_chunk]
            pts = np.array([walls[w] for w in chunk], dtype=np.float64)  # (k, n_points, 2)
            first = _first_contact(pts, i, j, closing)
            if first is not None:
                row, a, b, how = first
                found.append((chunk[row], a, b, how))
                break  # later chunks hold later walls of this size
    return min(found) if found else None


def _first_contact(
    pts: npt.NDArray[np.float64],
    i: npt.NDArray[np.intp],
    j: npt.NDArray[np.intp],
    closing: npt.NDArray[np.bool_],
) -> tuple[int, int, int, str] | None:
    """:func:`first_wall_contact` for (k, n, 2) walls of n points, as (row, i, j, how)."""
    k, n_seg = pts.shape[0], pts.shape[1] - 1
    closed = np.all(pts[:, 0] == pts[:, -1], axis=1) & (n_seg >= 3)  # (k,)
    # Contiguous (k, n_seg) arrays: np.take gathers from them several times faster than
    # fancy indexing of strided views.
    x, y = np.ascontiguousarray(pts[..., 0]), np.ascontiguousarray(pts[..., 1])
    dx, dy = np.diff(x, axis=1), np.diff(y, axis=1)  # segment vectors; segment m starts at m

    # Neighbours share a point by construction; they overlap only if they turn back.
    def turns_back(ux: Any, uy: Any, vx: Any, vy: Any) -> Any:
        sine = ux * vy - uy * vx
        return (np.abs(sine) <= _FOLD_TOLERANCE * np.hypot(ux, uy) * np.hypot(vx, vy)) & (
            ux * vx + uy * vy < 0
        )

    folds = turns_back(dx[:, :-1], dy[:, :-1], dx[:, 1:], dy[:, 1:])  # pairs (m, m + 1)
    closure_folds = closed & turns_back(dx[:, -1], dy[:, -1], dx[:, 0], dy[:, 0])  # (0, last)

    meets = np.zeros((k, i.size), dtype=np.bool_)
    how_cross = meets
    if i.size:

        def gather(values: Any, index: Any) -> Any:
            return np.take(values, index, axis=1)

        dxi, dyi, dxj, dyj = gather(dx, i), gather(dy, i), gather(dx, j), gather(dy, j)
        # Start of i minus start of j.
        ex, ey = gather(x, i) - gather(x, j), gather(y, i) - gather(y, j)
        # Turns (signs of cross products) of each segment's ends about the other segment.
        d1 = dxj * ey - dyj * ex  # start of i about j
        d2 = dxj * (ey + dyi) - dyj * (ex + dxi)  # end of i about j
        d3 = dyi * ex - dxi * ey  # start of j about i
        d4 = dxi * (dyj - ey) - dyi * (dxj - ex)  # end of j about i
        how_cross = (np.sign(d1) * np.sign(d2) < 0) & (np.sign(d3) * np.sign(d4) < 0)
        meets = how_cross.copy()
        # An end on the other segment's line touches it if it lies within the segment's box;
        # such pairs are few, so test only them.
        rows, cols = np.nonzero((d1 == 0) | (d2 == 0) | (d3 == 0) | (d4 == 0))
        if rows.size:
            p1, p2 = pts[rows, i[cols]], pts[rows, i[cols] + 1]
            q1, q2 = pts[rows, j[cols]], pts[rows, j[cols] + 1]

            def on(o: Any, u: Any, v: Any, d: Any) -> Any:
                lo, hi = np.minimum(o, u), np.maximum(o, u)
                inside = (lo[:, 0] <= v[:, 0]) & (v[:, 0] <= hi[:, 0])
                return (d == 0) & inside & (lo[:, 1] <= v[:, 1]) & (v[:, 1] <= hi[:, 1])

            touch = (
                on(q1, q2, p1, d1[rows, cols])
                | on(q1, q2, p2, d2[rows, cols])
                | on(p1, p2, q1, d3[rows, cols])
                | on(p1, p2, q2, d4[rows, cols])
            )
            meets[rows[touch], cols[touch]] = True
        meets &= ~(closed[:, None] & closing[None, :])

    bad_rows = np.flatnonzero(meets.any(axis=1) | folds.any(axis=1) | closure_folds)
    if not bad_rows.size:
        return None
    row = int(bad_rows[0])
    candidates: list[tuple[int, int, str]] = []
    for c in np.flatnonzero(meets[row])[:1]:  # pairs run in (i, j) order
        candidates.append((int(i[c]), int(j[c]), "cross" if how_cross[row, c] else "touch"))
    for m in np.flatnonzero(folds[row])[:1]:
        candidates.append((int(m), int(m) + 1, "turn back on each other"))
    if closure_folds[row]:
        candidates.append((0, n_seg - 1, "turn back on each other"))
    a, b, how = min(candidates)
    return row, a, b, how
