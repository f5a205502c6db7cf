"""A 2-D world of obstacles at sensor height, its TOML file format, and vectorised ray casting.

Frames follow REP-103: x forward, y left, angles counter-clockwise. Inside the code every
angle is in radians and every length in metres; only the TOML keys named ``*_deg`` hold
degrees. All coordinates are in the world frame unless stated otherwise.

A world holds three kinds of obstacle, which are flattened into two kinds of primitive:

* ``wall``: a polyline; each of its ``n - 1`` pieces is a line segment;
* ``box``: a rectangle of ``size = (length, width)`` turned by ``yaw``; four segments;
* ``cylinder``: a circle.

World file (TOML, read with :mod:`tomllib`)::

    name = "optional string"            # default: the file's stem ("" for text or a mapping)
    [vehicle]
    pose = [x_m, y_m, yaw_deg]          # optional; default [0, 0, 0]
    [[wall]]
    points = [[x, y], [x, y], ...]      # a polyline of at least 2 points
    reflectivity = 1.0                  # optional; 1.0 = off-white cardboard; > 0
    [[box]]
    center = [x, y]
    size = [length, width]              # along the box's own x and y axes; > 0
    yaw_deg = 0.0                       # optional
    reflectivity = 1.0                  # optional
    [[cylinder]]
    center = [x, y]
    radius = 0.1                        # > 0
    reflectivity = 1.0                  # optional

Every problem in a world raises :class:`~agent.errors.WorldFileError` with a one-line message
naming the file and the entry (entries are numbered from 1), e.g.
``world file w.toml: [[box]] 2: size must be two positive numbers, got [0.4, -1]``.

Obstacles are identified by their *id*: their position in the ``obstacles`` of the world that
was parsed or built (walls first, then boxes, then cylinders, each in file order). A world cut
down by :meth:`World.nearby` keeps the ids of its parent, so ray hits in the small world name
the same obstacles as in the full one.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NoReturn

import numpy as np
import numpy.typing as npt

from agent.errors import WorldFileError

__all__ = [
    "Obstacle",
    "ObstacleKind",
    "RayHits",
    "World",
    "cast_rays",
    "load_world",
    "parse_world",
    "ray_directions",
    "segment_clear",
    "world_from_obstacles",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
ObstacleKind = Literal["wall", "box", "cylinder"]
Point = tuple[float, float]
Pose = tuple[float, float, float]

DEFAULT_REFLECTIVITY = 1.0
"""Reflectivity of an entry that gives none: off-white cardboard, the reference surface."""

_KINDS: tuple[ObstacleKind, ...] = ("wall", "box", "cylinder")
_TOP_LEVEL_KEYS = ("name", "vehicle", *_KINDS)
_ENTRY_KEYS: dict[ObstacleKind, tuple[str, ...]] = {
    "wall": ("points", "reflectivity"),
    "box": ("center", "size", "yaw_deg", "reflectivity"),
    "cylinder": ("center", "radius", "reflectivity"),
}
_REQUIRED_KEYS: dict[ObstacleKind, tuple[str, ...]] = {
    "wall": ("points",),
    "box": ("center", "size"),
    "cylinder": ("center", "radius"),
}
_VEHICLE_KEYS = ("pose",)

# Ray casting works on blocks of rays so that one block's (rays x primitives) temporaries stay
# near this many elements: small enough for the CPU cache, large enough to amortise numpy's
# per-call overhead.
_BLOCK_ELEMENTS = 1 << 16
# At most this many rays per block, so that a block of a scan covers a narrow sector and the
# per-block culling (see `_Blocks.candidates`) drops most obstacles.
_BLOCK_RAYS = 256
# Up to this many ray-primitive pairs, all rays are tested against all primitives at once.
_SMALL_PROBLEM = 1 << 14
# A ray and a segment whose directions' sine is below this are taken as parallel (no hit).
_PARALLEL_SINE = 1e-12
# Stands for "no hit" inside the ray-casting kernel: larger than any distance it can return.
_NO_HIT = 1e300


# --------------------------------------------------------------------------------------------
# Data types
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Obstacle:
    """One parsed world entry.

    Attributes
    ----------
    kind
        ``"wall"``, ``"box"`` or ``"cylinder"``.
    index
        Position among the entries of its kind, from 0 (messages number entries from 1).
    id
        Position in the ``obstacles`` of the world it was parsed or built into; the value that
        :attr:`World.segments_obstacle`, :attr:`World.circles_obstacle` and
        :attr:`RayHits.obstacle` hold for it.
    reflectivity
        Relative reflectivity, > 0 (1.0 = off-white cardboard).
    points
        ((x, y), ...) in metres: a wall's polyline, or a box's four corners counter-clockwise
        starting at (+length/2, -width/2) in the box frame; empty for a cylinder.
    center
        (x, y) in metres for a box or a cylinder; ``None`` for a wall.
    size
        (length, width) in metres for a box; ``None`` otherwise.
    yaw_rad
        A box's heading in radians; 0.0 otherwise.
    radius
        A cylinder's radius in metres; ``None`` otherwise.
    """

    kind: ObstacleKind
    index: int
    id: int
    reflectivity: float
    points: tuple[Point, ...] = ()
    center: Point | None = None
    size: Point | None = None
    yaw_rad: float = 0.0
    radius: float | None = None

    def bounding_circle(self) -> tuple[Point, float]:
        """Return ``((x, y), r)``: a circle in metres that contains the whole obstacle."""
        if self.kind == "cylinder" and self.center is not None and self.radius is not None:
            return self.center, self.radius
        pts = np.asarray(self.points, dtype=np.float64).reshape(-1, 2)
        mid = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        r = float(np.max(np.hypot(pts[:, 0] - mid[0], pts[:, 1] - mid[1])))
        return (float(mid[0]), float(mid[1])), r


def _frozen(
    value: npt.ArrayLike, dtype: type[np.float64] | type[np.int64], shape: tuple[int, ...]
) -> Any:
    """Return a read-only copy of ``value`` as ``dtype``; ``-1`` in ``shape`` matches any size."""
    arr = np.array(value, dtype=dtype, copy=True)
    if arr.size == 0:
        arr = arr.reshape(tuple(0 if s == -1 else s for s in shape))
    if arr.ndim != len(shape) or any(
        s not in (-1, a) for s, a in zip(shape, arr.shape, strict=True)
    ):
        raise ValueError(f"expected an array of shape {shape}, got {arr.shape}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class World:
    """A 2-D plan of obstacles at sensor height, flattened into segments and circles.

    The arrays are copied and made read-only on construction. Build a world with
    :func:`load_world`, :func:`parse_world` or :func:`world_from_obstacles` rather than by
    hand: those fill both the arrays and the matching :attr:`obstacles`.

    Attributes
    ----------
    segments_start, segments_end
        (m, 2) float64, metres, world frame: the ends of every wall piece and box face.
    segments_reflectivity
        (m,) float64, > 0.
    segments_obstacle
        (m,) int64: the :attr:`Obstacle.id` each segment belongs to.
    circles_center
        (k, 2) float64, metres, world frame.
    circles_radius
        (k,) float64, metres, > 0.
    circles_reflectivity
        (k,) float64, > 0.
    circles_obstacle
        (k,) int64: the :attr:`Obstacle.id` each circle belongs to.
    obstacles
        The obstacles, walls then boxes then cylinders, each kind in file order.
    vehicle_pose
        (x_m, y_m, yaw_rad) of the vehicle in the world frame.
    name
        A label for messages and plots.
    """

    segments_start: FloatArray
    segments_end: FloatArray
    segments_reflectivity: FloatArray
    segments_obstacle: IntArray
    circles_center: FloatArray
    circles_radius: FloatArray
    circles_reflectivity: FloatArray
    circles_obstacle: IntArray
    obstacles: tuple[Obstacle, ...]
    vehicle_pose: Pose = (0.0, 0.0, 0.0)
    name: str = ""
    _bounds_center: FloatArray = field(init=False, repr=False)
    _bounds_radius: FloatArray = field(init=False, repr=False)
    _obstacle_ids: IntArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        m = np.shape(self.segments_start)[0] if np.ndim(self.segments_start) else -1
        k = np.shape(self.circles_center)[0] if np.ndim(self.circles_center) else -1
        arrays: dict[str, tuple[type[np.float64] | type[np.int64], tuple[int, ...]]] = {
            "segments_start": (np.float64, (m, 2)),
            "segments_end": (np.float64, (m, 2)),
            "segments_reflectivity": (np.float64, (m,)),
            "segments_obstacle": (np.int64, (m,)),
            "circles_center": (np.float64, (k, 2)),
            "circles_radius": (np.float64, (k,)),
            "circles_reflectivity": (np.float64, (k,)),
            "circles_obstacle": (np.int64, (k,)),
        }
        for attr, (dtype, shape) in arrays.items():
            try:
                arr = _frozen(getattr(self, attr), dtype, shape)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"World.{attr}: {exc}") from None
            if dtype is np.float64 and not np.all(np.isfinite(arr)):
                raise ValueError(f"World.{attr} must be finite")
            object.__setattr__(self, attr, arr)
        for attr in ("segments_reflectivity", "circles_radius", "circles_reflectivity"):
            if np.any(getattr(self, attr) <= 0.0):
                raise ValueError(f"World.{attr} must be > 0")
        pose = tuple(float(v) for v in self.vehicle_pose)
        if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
            raise ValueError(f"World.vehicle_pose must be three finite numbers, got {pose}")
        object.__setattr__(self, "vehicle_pose", pose)
        obstacles = tuple(self.obstacles)
        object.__setattr__(self, "obstacles", obstacles)
        ids = _frozen([o.id for o in obstacles], np.int64, (-1,))
        if np.unique(ids).size != ids.size:
            raise ValueError("World.obstacles: obstacle ids must be unique")
        for attr in ("segments_obstacle", "circles_obstacle"):
            if not np.all(np.isin(getattr(self, attr), ids)):
                raise ValueError(f"World.{attr} names an obstacle id not in World.obstacles")
        circles = [o.bounding_circle() for o in obstacles]
        object.__setattr__(self, "_obstacle_ids", ids)
        object.__setattr__(
            self, "_bounds_center", _frozen([c for c, _ in circles], np.float64, (-1, 2))
        )
        object.__setattr__(
            self, "_bounds_radius", _frozen([r for _, r in circles], np.float64, (-1,))
        )

    @classmethod
    def build(
        cls,
        walls: Iterable[tuple[npt.ArrayLike, float]] = (),
        boxes: Iterable[tuple[npt.ArrayLike, npt.ArrayLike, float, float]] = (),
        cylinders: Iterable[tuple[npt.ArrayLike, float, float]] = (),
        vehicle_pose: npt.ArrayLike = (0.0, 0.0, 0.0),
        name: str = "",
    ) -> World:
        """Same as :func:`world_from_obstacles`."""
        return world_from_obstacles(walls, boxes, cylinders, vehicle_pose, name)

    @property
    def n_obstacles(self) -> int:
        """Number of obstacles in :attr:`obstacles`."""
        return len(self.obstacles)

    def nearby(self, center_xy: npt.ArrayLike, radius_m: float) -> World:
        """Return the world cut down to the obstacles that may lie within ``radius_m``.

        Parameters
        ----------
        center_xy
            (2,) point in the world frame, metres.
        radius_m
            Distance in metres, >= 0 (``inf`` keeps everything).

        Returns
        -------
        World
            A world holding only the obstacles whose bounding circle comes within ``radius_m``
            of ``center_xy``, with their segments and circles. Obstacle ids are those of this
            world, so hits found in the small world name the same obstacles. The vehicle pose
            and name are kept.
        """
        c = np.asarray(center_xy, dtype=np.float64)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ValueError(f"center_xy must be a finite (2,) point, got {center_xy!r}")
        if not radius_m >= 0.0:
            raise ValueError(f"radius_m must be >= 0, got {radius_m!r}")
        gap = (
            np.hypot(self._bounds_center[:, 0] - c[0], self._bounds_center[:, 1] - c[1])
            - self._bounds_radius
        )
        keep = gap <= radius_m
        kept_ids = self._obstacle_ids[keep]
        seg = np.isin(self.segments_obstacle, kept_ids)
        circ = np.isin(self.circles_obstacle, kept_ids)
        return World(
            segments_start=self.segments_start[seg],
            segments_end=self.segments_end[seg],
            segments_reflectivity=self.segments_reflectivity[seg],
            segments_obstacle=self.segments_obstacle[seg],
            circles_center=self.circles_center[circ],
            circles_radius=self.circles_radius[circ],
            circles_reflectivity=self.circles_reflectivity[circ],
            circles_obstacle=self.circles_obstacle[circ],
            obstacles=tuple(o for o, k in zip(self.obstacles, keep.tolist(), strict=True) if k),
            vehicle_pose=self.vehicle_pose,
            name=self.name,
        )


@dataclass(frozen=True, eq=False)
class RayHits:
    """The first surface each ray meets. Arrays are read-only.

    Attributes
    ----------
    distance_m
        (n,) float64: distance along the ray to the hit, metres; ``inf`` where nothing is hit.
    normal
        (n, 2) float64: unit surface normal at the hit, world frame, turned back toward the
        ray (``dot(normal, direction) <= 0``); NaN where nothing is hit.
    reflectivity
        (n,) float64: reflectivity of the surface hit; NaN where nothing is hit.
    obstacle
        (n,) int64: :attr:`Obstacle.id` of the obstacle hit; -1 where nothing is hit.
    """

    distance_m: FloatArray
    normal: FloatArray
    reflectivity: FloatArray
    obstacle: IntArray

    @property
    def hit(self) -> BoolArray:
        """(n,) bool: True where the ray hit something."""
        return np.isfinite(self.distance_m)


# --------------------------------------------------------------------------------------------
# Building worlds
# --------------------------------------------------------------------------------------------


def _box_corners(center: Point, size: Point, yaw_rad: float) -> tuple[Point, ...]:
    """Four corners of a box, counter-clockwise from (+length/2, -width/2) in its own frame."""
    hl, hw = 0.5 * size[0], 0.5 * size[1]
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    local = ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))
    return tuple((center[0] + cy * lx - sy * ly, center[1] + sy * lx + cy * ly) for lx, ly in local)


def _assemble(
    walls: Sequence[tuple[tuple[Point, ...], float]],
    boxes: Sequence[tuple[Point, Point, float, float]],
    cylinders: Sequence[tuple[Point, float, float]],
    vehicle_pose: Pose,
    name: str,
) -> World:
    """Build a world from already validated entries, numbering obstacles in order."""
    obstacles: list[Obstacle] = []
    starts: list[Point] = []
    ends: list[Point] = []
    seg_refl: list[float] = []
    seg_obs: list[int] = []

    def add_polyline(points: tuple[Point, ...], closed: bool, refl: float, oid: int) -> None:
        pts = (*points, points[0]) if closed else points
        starts.extend(pts[:-1])
        ends.extend(pts[1:])
        seg_refl.extend([refl] * (len(pts) - 1))
        seg_obs.extend([oid] * (len(pts) - 1))

    for i, (points, refl) in enumerate(walls):
        oid = len(obstacles)
        obstacles.append(Obstacle("wall", i, oid, refl, points=points))
        add_polyline(points, False, refl, oid)
    for i, (center, size, yaw, refl) in enumerate(boxes):
        oid = len(obstacles)
        corners = _box_corners(center, size, yaw)
        obstacles.append(
            Obstacle("box", i, oid, refl, corners, center=center, size=size, yaw_rad=yaw)
        )
        add_polyline(corners, True, refl, oid)
    first_circle = len(obstacles)
    for i, (center, radius, refl) in enumerate(cylinders):
        obstacles.append(
            Obstacle("cylinder", i, len(obstacles), refl, center=center, radius=radius)
        )
    return World(
        segments_start=np.array(starts, dtype=np.float64).reshape(-1, 2),
        segments_end=np.array(ends, dtype=np.float64).reshape(-1, 2),
        segments_reflectivity=np.array(seg_refl, dtype=np.float64),
        segments_obstacle=np.array(seg_obs, dtype=np.int64),
        circles_center=np.array([c[0] for c in cylinders], dtype=np.float64).reshape(-1, 2),
        circles_radius=np.array([c[1] for c in cylinders], dtype=np.float64),
        circles_reflectivity=np.array([c[2] for c in cylinders], dtype=np.float64),
        circles_obstacle=np.arange(first_circle, len(obstacles), dtype=np.int64),
        obstacles=tuple(obstacles),
        vehicle_pose=vehicle_pose,
        name=name,
    )


def world_from_obstacles(
    walls: Iterable[tuple[npt.ArrayLike, float]] = (),
    boxes: Iterable[tuple[npt.ArrayLike, npt.ArrayLike, float, float]] = (),
    cylinders: Iterable[tuple[npt.ArrayLike, float, float]] = (),
    vehicle_pose: npt.ArrayLike = (0.0, 0.0, 0.0),
    name: str = "",
) -> World:
    """Build a world in code, with the same checks as a world file.

    Parameters
    ----------
    walls
        ``(points, reflectivity)`` per wall; ``points`` (p, 2) metres, p >= 2, a polyline.
    boxes
        ``(center, size, yaw_rad, reflectivity)`` per box; ``center`` (2,) metres, ``size``
        (length, width) metres along the box's own x and y axes, ``yaw_rad`` radians.
    cylinders
        ``(center, radius, reflectivity)`` per cylinder; metres.
    vehicle_pose
        (x_m, y_m, yaw_rad).
    name
        A label.

    Returns
    -------
    World
        Obstacle ids: walls first, then boxes, then cylinders, each in the order given.

    Raises
    ------
    WorldFileError
        With no path, naming the entry as a world file would (``[[box]] 2: ...``).
    """
    chk = _Checker(None)

    def plain(value: Any) -> Any:
        """``value`` with numpy arrays, at any depth, turned into lists."""
        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, list | tuple):
            return [plain(v) for v in value]
        return value

    def unpack(entry: Any, n: int, where: str, fields: str) -> tuple[Any, ...]:
        if not isinstance(entry, Sequence) or isinstance(entry, str) or len(entry) != n:
            chk.fail(where, f"must be a tuple {fields}, got {_show(entry)}")
        return tuple(plain(v) for v in entry)

    wall_list: list[tuple[tuple[Point, ...], float]] = []
    for i, wall in enumerate(walls):
        where = f"[[wall]] {i + 1}"
        points, refl = unpack(wall, 2, where, "(points, reflectivity)")
        wall_list.append((chk.polyline(points, where), chk.positive(refl, where, "reflectivity")))
    box_list: list[tuple[Point, Point, float, float]] = []
    for i, box in enumerate(boxes):
        where = f"[[box]] {i + 1}"
        center, size, yaw, refl = unpack(box, 4, where, "(center, size, yaw_rad, reflectivity)")
        box_list.append(
            (
                chk.point(center, where, "center"),
                chk.positive_pair(size, where, "size"),
                chk.finite(yaw, where, "yaw_rad"),
                chk.positive(refl, where, "reflectivity"),
            )
        )
    cyl_list: list[tuple[Point, float, float]] = []
    for i, cyl in enumerate(cylinders):
        where = f"[[cylinder]] {i + 1}"
        center, radius, refl = unpack(cyl, 3, where, "(center, radius, reflectivity)")
        cyl_list.append(
            (
                chk.point(center, where, "center"),
                chk.positive(radius, where, "radius"),
                chk.positive(refl, where, "reflectivity"),
            )
        )
    pose = chk.numbers(plain(vehicle_pose), 3, "vehicle_pose", "", "[x_m, y_m, yaw_rad]")
    if not isinstance(name, str):
        chk.fail("name", f"must be a string, got {_show(name)}")
    return _assemble(wall_list, box_list, cyl_list, (pose[0], pose[1], pose[2]), name)


# --------------------------------------------------------------------------------------------
# World files
# --------------------------------------------------------------------------------------------


def _show(value: Any, limit: int = 60) -> str:
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


class _Checker:
    """Validation helpers that raise :class:`WorldFileError` naming ``path`` and the entry."""

    def __init__(self, path: str | Path | None) -> None:
        self.path = path

    def fail(self, where: str, problem: str) -> NoReturn:
        raise WorldFileError(self.path, f"{where}: {problem}" if where else problem)

    def finite(self, value: Any, where: str, key: str) -> float:
        x = _finite(value)
        if x is None:
            self.fail(where, f"{key} must be a finite number, got {_show(value)}")
        return x

    def positive(self, value: Any, where: str, key: str) -> float:
        x = _finite(value)
        if x is None or not x > 0.0:
            self.fail(where, f"{key} must be a finite positive number, got {_show(value)}")
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
            self.fail(where, f"{label} {count} finite numbers {what}, got {_show(value)}")
        return tuple(xs)

    def point(self, value: Any, where: str, key: str) -> Point:
        x, y = self.numbers(value, 2, where, key, "[x, y]")
        return (x, y)

    def positive_pair(self, value: Any, where: str, key: str) -> Point:
        xs = self._floats(value, 2)
        if xs is None or not (xs[0] > 0.0 and xs[1] > 0.0):
            self.fail(where, f"{key} must be two positive numbers, got {_show(value)}")
        return (xs[0], xs[1])

    def polyline(self, value: Any, where: str) -> tuple[Point, ...]:
        if not isinstance(value, list | tuple):
            self.fail(where, f"points must be a list of [x, y] pairs, got {_show(value)}")
        if len(value) < 2:
            self.fail(where, f"points must hold at least 2 points, got {len(value)}")
        pts = tuple(self.point(p, where, f"point {j + 1} of points") for j, p in enumerate(value))
        for j in range(len(pts) - 1):
            if pts[j] == pts[j + 1]:
                self.fail(
                    where,
                    f"zero-length segment: points {j + 1} and {j + 2} are both "
                    f"{_show(list(pts[j]))}",
                )
        return pts

    def table(self, value: Any, where: str, allowed: tuple[str, ...]) -> Mapping[str, Any]:
        """``value`` as a table with keys from ``allowed`` only."""
        if not isinstance(value, Mapping):
            self.fail(where, f"must be a table, got {_show(value)}")
        for key in value:
            if key not in allowed:
                self.fail(
                    where,
                    f"unknown key {_show(key)}; allowed keys: {', '.join(allowed)}",
                )
        return value


def _parse_mapping(doc: Mapping[str, Any], path: str | Path | None) -> World:
    chk = _Checker(path)
    if not isinstance(doc, Mapping):
        chk.fail("", f"a world must be a table, got {_show(doc)}")
    for key in doc:
        if key not in _TOP_LEVEL_KEYS:
            chk.fail(
                "",
                f"unknown top-level key {_show(key)}; allowed keys: {', '.join(_TOP_LEVEL_KEYS)}",
            )

    name = doc.get("name", Path(path).stem if path is not None else "")
    if not isinstance(name, str):
        chk.fail("", f"name must be a string, got {_show(name)}")

    pose: Pose = (0.0, 0.0, 0.0)
    if "vehicle" in doc:
        vehicle = chk.table(doc["vehicle"], "[vehicle]", _VEHICLE_KEYS)
        if "pose" in vehicle:
            x, y, yaw_deg = chk.numbers(
                vehicle["pose"], 3, "[vehicle]", "pose", "[x_m, y_m, yaw_deg]"
            )
            pose = (x, y, math.radians(yaw_deg))

    entries: dict[ObstacleKind, list[Mapping[str, Any]]] = {}
    for kind in _KINDS:
        raw = doc.get(kind, [])
        if not isinstance(raw, list | tuple):
            chk.fail("", f"{kind} must be an array of tables [[{kind}]], got {_show(raw)}")
        tables: list[Mapping[str, Any]] = []
        for i, entry in enumerate(raw):
            where = f"[[{kind}]] {i + 1}"
            table = chk.table(entry, where, _ENTRY_KEYS[kind])
            for key in _REQUIRED_KEYS[kind]:
                if key not in table:
                    chk.fail(where, f"missing key {_show(key)}")
            tables.append(table)
        entries[kind] = tables

    def refl(table: Mapping[str, Any], where: str) -> float:
        return chk.positive(table.get("reflectivity", DEFAULT_REFLECTIVITY), where, "reflectivity")

    walls = [
        (chk.polyline(t["points"], f"[[wall]] {i + 1}"), refl(t, f"[[wall]] {i + 1}"))
        for i, t in enumerate(entries["wall"])
    ]
    boxes: list[tuple[Point, Point, float, float]] = []
    for i, t in enumerate(entries["box"]):
        where = f"[[box]] {i + 1}"
        boxes.append(
            (
                chk.point(t["center"], where, "center"),
                chk.positive_pair(t["size"], where, "size"),
                math.radians(chk.finite(t.get("yaw_deg", 0.0), where, "yaw_deg")),
                refl(t, where),
            )
        )
    cylinders: list[tuple[Point, float, float]] = []
    for i, t in enumerate(entries["cylinder"]):
        where = f"[[cylinder]] {i + 1}"
        cylinders.append(
            (
                chk.point(t["center"], where, "center"),
                chk.positive(t["radius"], where, "radius"),
                refl(t, where),
            )
        )
    return _assemble(walls, boxes, cylinders, pose, name)


def parse_world(text_or_mapping: str | Mapping[str, Any], path: str | Path | None = None) -> World:
    """Build a world from TOML text or from an already parsed mapping.

    Parameters
    ----------
    text_or_mapping
        TOML text, or a mapping shaped like :func:`tomllib.loads`'s result.
    path
        The file the text came from, used in error messages and as the default name.

    Returns
    -------
    World

    Raises
    ------
    WorldFileError
        If the text is not TOML or does not describe a valid world.
    """
    if isinstance(text_or_mapping, str):
        try:
            doc: Mapping[str, Any] = tomllib.loads(text_or_mapping)
        except tomllib.TOMLDecodeError as exc:
            raise WorldFileError(path, "not valid TOML: " + " ".join(str(exc).split())) from None
    else:
        doc = text_or_mapping
    return _parse_mapping(doc, path)


def load_world(path: str | Path) -> World:
    """Read and parse a world file.

    Parameters
    ----------
    path
        A TOML world file (UTF-8).

    Returns
    -------
    World
        Named after ``name`` in the file, else after the file's stem.

    Raises
    ------
    WorldFileError
        If the file cannot be read, is not TOML, or does not describe a valid world.
    """
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise WorldFileError(path, "no such file") from None
    except OSError as exc:
        raise WorldFileError(path, f"cannot read: {exc.strerror or type(exc).__name__}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise WorldFileError(path, f"not UTF-8 text (byte {exc.start})") from None
    return parse_world(text, path)


# --------------------------------------------------------------------------------------------
# Ray casting
# --------------------------------------------------------------------------------------------


def ray_directions(headings_rad: npt.ArrayLike) -> FloatArray:
    """Unit direction vectors for headings.

    Parameters
    ----------
    headings_rad
        (...) headings in radians, counter-clockwise from +x.

    Returns
    -------
    numpy.ndarray
        (..., 2) float64 ``[cos, sin]``.
    """
    h = np.asarray(headings_rad, dtype=np.float64)
    return np.stack([np.cos(h), np.sin(h)], axis=-1)


def _rays(origins: npt.ArrayLike, directions: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Check rays; return origins (n, 2) or (1, 2) and unit directions (n, 2)."""
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    if o.ndim not in (1, 2) or o.shape[-1] != 2 or d.ndim not in (1, 2) or d.shape[-1] != 2:
        raise ValueError(f"origins and directions must be (n, 2) or (2,), got {o.shape}, {d.shape}")
    o2, d2 = np.atleast_2d(o), np.atleast_2d(d)
    n = max(o2.shape[0], d2.shape[0])
    if o2.shape[0] not in (1, n) or d2.shape[0] not in (1, n):
        raise ValueError(f"origins {o.shape} and directions {d.shape} do not match")
    if not (np.all(np.isfinite(o2)) and np.all(np.isfinite(d2))):
        raise ValueError("origins and directions must be finite")
    norm = np.hypot(d2[:, 0], d2[:, 1])
    if np.any(norm == 0.0):
        raise ValueError("directions must not be zero vectors")
    return o2, np.broadcast_to(d2 / norm[:, None], (n, 2))


@dataclass(frozen=True)
class _Blocks:
    """Bounds on the rays of each block of consecutive rays (nb blocks).

    Every ray of block i starts within ``spread[i]`` of ``origin[i]``, points within
    ``half_angle[i]`` radians of the unit vector ``axis[i]`` (a half angle of pi bounds
    nothing), and accepts hits no farther than ``reach[i]``.
    """

    starts: IntArray  # (nb,) index of each block's first ray
    origin: FloatArray  # (nb, 2)
    spread: FloatArray  # (nb,)
    axis: FloatArray  # (nb, 2)
    half_angle: FloatArray  # (nb,)
    reach: FloatArray  # (nb,)

    @classmethod
    def of(cls, P: FloatArray, D: FloatArray, t_max: FloatArray, size: int) -> _Blocks:
        n = D.shape[0]
        starts = np.arange(0, n, size)
        counts = np.diff(np.append(starts, n))[:, None]
        block_of = np.repeat(np.arange(starts.size), counts[:, 0])
        if P.shape[0] == 1:
            origin = np.broadcast_to(P, (starts.size, 2))
            spread = np.zeros(starts.size)
        else:
            origin = np.add.reduceat(P, starts, axis=0) / counts
            off = P - origin[block_of]
            spread = np.maximum.reduceat(np.hypot(off[:, 0], off[:, 1]), starts)
        mean_d = np.add.reduceat(D, starts, axis=0) / counts
        norm = np.hypot(mean_d[:, 0], mean_d[:, 1])
        # Directions spread over more than a half-turn give no useful bound.
        useful = norm > 0.5
        axis = mean_d / np.where(useful, norm, 1.0)[:, None]
        cos_min = np.minimum.reduceat(np.sum(D * axis[block_of], axis=1), starts)
        half_angle = np.where(useful, np.arccos(np.clip(cos_min, -1.0, 1.0)), math.pi)
        reach = np.maximum.reduceat(t_max, starts)
        return cls(starts, origin, spread, axis, half_angle, reach)

    def candidates(self, center: FloatArray, radius: FloatArray, group: slice) -> BoolArray:
        """(g, q) bool: True where some ray of block ``group`` may hit the primitive.

        A conservative test on bounding circles (``center`` (q, 2), ``radius`` (q,)): a ray
        from within ``spread`` of ``origin`` that meets a circle of radius ``radius`` points
        within ``asin((radius + spread) / dist)`` of the direction from ``origin`` to ``center``.
        """
        origin, axis = self.origin[group], self.axis[group]
        vx = center[None, :, 0] - origin[:, 0:1]  # (g, q)
        vy = center[None, :, 1] - origin[:, 1:2]
        dist = np.hypot(vx, vy)
        r = radius + self.spread[group, None]
        outside = dist > r
        dist = np.where(outside, dist, 1.0)
        gamma = np.arcsin(np.where(outside, r / dist, 1.0))
        cos_beta = (vx * axis[:, 0:1] + vy * axis[:, 1:2]) / dist
        beta = np.arccos(np.clip(cos_beta, -1.0, 1.0))
        in_cone = beta <= self.half_angle[group, None] + gamma + 1e-9
        in_reach = dist - r <= self.reach[group, None]
        return ~outside | (in_cone & in_reach)


def _first_hits(
    world: World, P: FloatArray, D: FloatArray, t_min: float, t_max: FloatArray
) -> tuple[FloatArray, IntArray, IntArray]:
    """Nearest hit per ray with ``t_min < t <= t_max``.

    Parameters
    ----------
    P
        (n, 2) or (1, 2) ray origins.
    D
        (n, 2) unit ray directions.
    t_min
        Lower bound on the distance, exclusive.
    t_max
        (n,) upper bound on the distance, inclusive (may be inf).

    Returns
    -------
    t, segment, circle
        (n,) distance (inf if no hit); (n,) index of the segment hit or -1; (n,) index of the
        circle hit or -1 (at most one of the two is >= 0).

    Notes
    -----
    Rays are processed in blocks of consecutive rays. For each block the segments and circles
    that no ray of the block can reach (by direction and distance) are dropped first, which
    pays off when consecutive rays start near each other and point in similar directions, as
    in a scan.
    """
    n = D.shape[0]
    t_best = np.full(n, np.inf)
    seg_best = np.full(n, -1, dtype=np.int64)
    circ_best = np.full(n, -1, dtype=np.int64)
    m, k = world.segments_start.shape[0], world.circles_center.shape[0]
    if n == 0 or m + k == 0:
        return t_best, seg_best, circ_best

    # Segment a + u e (u in [0, 1], e = b - a) and ray p + t d, with x the 2-D cross product:
    # the ray's line crosses the segment where s_a = d x (a - p) and s_b = d x (b - p) differ in
    # sign (or one is zero), at t = (a - p) x e / (d x e), and d x e = s_b - s_a. All the
    # (rays x segments) products are matmuls; masks never index (random masks are slow).
    a, b_ = world.segments_start, world.segments_end
    e = b_ - a
    seg_half = 0.5 * np.hypot(e[:, 0], e[:, 1])
    parallel = 2.0 * _PARALLEL_SINE * seg_half  # (m,)
    shared = P.shape[0] == 1
    if shared:
        ap, bp = a - P[0], b_ - P[0]  # (m, 2), relative to the common origin
        sa_all = np.stack([ap[:, 1], -ap[:, 0]])  # (2, m): d @ sa_all = d x (a - p)
        sb_all = np.stack([bp[:, 1], -bp[:, 0]])
        t_num_all = ap[:, 0] * e[:, 1] - ap[:, 1] * e[:, 0]  # (m,): (a - p) x e
    else:
        sa_all = np.stack([a[:, 1], -a[:, 0]])  # (2, m): d @ sa_all = d x a
        sb_all = np.stack([e[:, 1], -e[:, 0]])  # (2, m): v @ sb_all = v x e
        t_num_all = a[:, 0] * e[:, 1] - a[:, 1] * e[:, 0]  # (m,): a x e
    c_all = world.circles_center
    r2_all = world.circles_radius**2

    size = max(1, min(_BLOCK_RAYS, _BLOCK_ELEMENTS // max(m, 2 * k, 1)))
    single = n * (m + 2 * k) <= _SMALL_PROBLEM  # one pass over everything: culling costs more
    if single:
        size = n
        starts = [0]
        seg_keep = np.ones((1, m), dtype=bool)
        circ_keep = np.ones((1, k), dtype=bool)
        group = 1
    else:
        blocks = _Blocks.of(P, D, t_max, size)
        starts = blocks.starts.tolist()
        seg_mid = 0.5 * (a + b_)
        group = max(1, _BLOCK_ELEMENTS // max(m, k, 1))  # blocks whose candidates come at once
    for bi, lo in enumerate(starts):
        gi = bi % group
        if gi == 0 and not single:
            sl = slice(bi, bi + group)
            seg_keep = blocks.candidates(seg_mid, seg_half, sl)
            circ_keep = blocks.candidates(c_all, world.circles_radius, sl)
        hi = min(n, lo + size)
        rows = np.arange(hi - lo)
        d = D[lo:hi]
        p = P if shared else P[lo:hi]
        tmax = t_max[lo:hi, None]

        si = np.flatnonzero(seg_keep[gi])
        if si.size:
            if shared:
                sa = d @ sa_all[:, si]  # (b, m')
                sb = d @ sb_all[:, si]
                denom = sb - sa  # d x e
                t = t_num_all[si] / denom
            else:
                d_cross_p = d[:, 0] * p[:, 1] - d[:, 1] * p[:, 0]  # (b,)
                sa = d @ sa_all[:, si] - d_cross_p[:, None]  # d x (a - p)
                denom = d @ sb_all[:, si]  # d x e
                sb = sa + denom
                t = (t_num_all[si] - p @ sb_all[:, si]) / denom
            sa *= sb
            ok = (sa <= 0.0) & (np.abs(denom) > parallel[si]) & (t > t_min) & (t <= tmax)
            key = _key(t, ok)
            j = np.argmin(key, axis=1)
            tj = key[rows, j]
            hit = tj < _NO_HIT
            t_best[lo:hi] = np.where(hit, tj, np.inf)
            seg_best[lo:hi] = np.where(hit, si[j], -1)

        ci = np.flatnonzero(circ_keep[gi])
        if ci.size:
            # |p + t d - c|^2 = r^2 with |d| = 1: t = -f.d -+ sqrt((f.d)^2 - |f|^2 + r^2),
            # f = p - c. Both roots are candidates; the nearest one in range wins, so a ray
            # starting inside a circle meets its far side. A miss makes the sqrt NaN.
            c = c_all[ci]
            fx = p[:, 0:1] - c[:, 0]  # (b or 1, k')
            fy = p[:, 1:2] - c[:, 1]
            fd = fx * d[:, 0:1] + fy * d[:, 1:2]  # (b, k')
            root = np.sqrt(fd * fd - (fx * fx + fy * fy - r2_all[ci]))
            t = np.concatenate([-fd - root, root - fd], axis=1)  # (b, 2k')
            ok = (t > t_min) & (t <= tmax)
            key = _key(t, ok)
            j = np.argmin(key, axis=1)
            tj = key[rows, j]
            better = tj < np.minimum(t_best[lo:hi], _NO_HIT)
            t_best[lo:hi] = np.where(better, tj, t_best[lo:hi])
            seg_best[lo:hi] = np.where(better, -1, seg_best[lo:hi])
            circ_best[lo:hi] = np.where(better, ci[j % ci.size], -1)
    return t_best, seg_best, circ_best


def _key(t: FloatArray, ok: BoolArray) -> FloatArray:
    """``t`` where ``ok``, else ``_NO_HIT`` (or more), without masked indexing.

    Valid ``t`` are > 0, so ``fmax(t, 0)`` keeps them; ``fmax`` also turns NaN into the penalty.
    Overwrites ``ok``.
    """
    np.logical_not(ok, out=ok)
    key = ok.astype(np.float64)
    key *= _NO_HIT
    return np.fmax(t, key, out=key)


def _range_bounds(min_range_m: float, max_range_m: float) -> None:
    if not (math.isfinite(min_range_m) and min_range_m >= 0.0):
        raise ValueError(f"min_range_m must be finite and >= 0, got {min_range_m!r}")
    if not max_range_m > min_range_m:
        raise ValueError(f"max_range_m must be > min_range_m, got {max_range_m!r}")


def _read_only(*arrays: npt.NDArray[Any]) -> None:
    for arr in arrays:
        arr.flags.writeable = False


def cast_rays(
    world: World,
    origins: npt.ArrayLike,
    directions: npt.ArrayLike,
    max_range_m: float = math.inf,
    min_range_m: float = 0.0,
) -> RayHits:
    """Find the first surface each ray meets.

    Parameters
    ----------
    world
        The obstacles (cull with :meth:`World.nearby` first for large worlds).
    origins
        (n, 2) or (2,) ray origins, world frame, metres.
    directions
        (n, 2) or (2,) ray directions, world frame; normalised here (see
        :func:`ray_directions` to make them from headings).
    max_range_m
        Hits farther than this are ignored (inclusive bound), metres.
    min_range_m
        Hits at or nearer than this are ignored (exclusive bound), metres, >= 0.

    Returns
    -------
    RayHits
        One entry per ray, ``n = max(len(origins), len(directions))``. A ray that starts inside
        a cylinder or box meets its wall from inside; its normal still points back at the ray.
        Rays parallel to a segment do not hit it.
    """
    _range_bounds(min_range_m, max_range_m)
    P, D = _rays(origins, directions)
    n = D.shape[0]
    with np.errstate(all="ignore"):
        t, seg, circ = _first_hits(world, P, D, min_range_m, np.full(n, float(max_range_m)))
    is_seg, is_circ = seg >= 0, circ >= 0
    normal = np.full((n, 2), np.nan)
    refl = np.full(n, np.nan)
    obstacle = np.full(n, -1, dtype=np.int64)
    if np.any(is_seg):
        j = seg[is_seg]
        e = world.segments_end[j] - world.segments_start[j]
        normal[is_seg] = np.stack([e[:, 1], -e[:, 0]], axis=1) / np.hypot(e[:, 0], e[:, 1])[:, None]
        refl[is_seg] = world.segments_reflectivity[j]
        obstacle[is_seg] = world.segments_obstacle[j]
    if np.any(is_circ):
        j = circ[is_circ]
        p = np.broadcast_to(P, (n, 2))[is_circ]
        hit_point = p + t[is_circ, None] * D[is_circ]
        normal[is_circ] = (hit_point - world.circles_center[j]) / world.circles_radius[j, None]
        refl[is_circ] = world.circles_reflectivity[j]
        obstacle[is_circ] = world.circles_obstacle[j]
        normal[is_circ] /= np.hypot(normal[is_circ, 0], normal[is_circ, 1])[:, None]
    flip = np.sum(normal * D, axis=1) > 0.0  # NaN rows compare False
    normal[flip] *= -1.0
    _read_only(t, normal, refl, obstacle)
    return RayHits(distance_m=t, normal=normal, reflectivity=refl, obstacle=obstacle)


def segment_clear(
    world: World, start: npt.ArrayLike, end: npt.ArrayLike, margin_m: float = 1e-6
) -> BoolArray:
    """Whether straight paths cross no obstacle (a line-of-sight test).

    Parameters
    ----------
    world
        The obstacles.
    start, end
        (n, 2) or (2,) path ends, world frame, metres.
    margin_m
        Surfaces within this distance (metres, >= 0) of either end are ignored, so a path that
        ends exactly on a surface (a laser spot) counts as clear.

    Returns
    -------
    numpy.ndarray
        (n,) bool: True where the path is clear. Paths no longer than ``2 * margin_m`` are clear.
    """
    if not (math.isfinite(margin_m) and margin_m >= 0.0):
        raise ValueError(f"margin_m must be finite and >= 0, got {margin_m!r}")
    s = np.atleast_2d(np.asarray(start, dtype=np.float64))
    e = np.atleast_2d(np.asarray(end, dtype=np.float64))
    if s.ndim != 2 or s.shape[1] != 2 or e.ndim != 2 or e.shape[1] != 2:
        raise ValueError(f"start and end must be (n, 2) or (2,), got {s.shape}, {e.shape}")
    s, e = np.broadcast_arrays(s, e)
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(e))):
        raise ValueError("start and end must be finite")
    delta = e - s
    length = np.hypot(delta[:, 0], delta[:, 1])
    clear = length <= 2.0 * margin_m
    test = ~clear
    if np.any(test):
        d = delta[test] / length[test, None]
        with np.errstate(all="ignore"):
            t, _, _ = _first_hits(world, s[test], d, margin_m, length[test] - margin_m)
        clear[test] = ~np.isfinite(t)
    return clear
