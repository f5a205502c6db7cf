"""A 2-D world of obstacles at sensor height, flattened into segments and circles.

Frames follow REP-103: x forward, y left, angles counter-clockwise. Inside the code every
angle is in radians and every length in metres. All coordinates are in the world frame unless
stated otherwise.

A world holds three kinds of obstacle, which are flattened into two kinds of primitive:

* ``wall``: a polyline; each of its ``n - 1`` pieces is a line segment;
* ``box``: a rectangle of ``size = (length, width)`` turned by ``yaw``; four segments;
* ``cylinder``: a circle.

A world may also hold *movers* (:class:`~agent.sim.movers.Mover`): cylinders that walk a
path back and forth; where one is depends on the time (:func:`~agent.sim.movers.mover_states`).
And it may carry a *task* (:class:`~agent.task.Task`): where the vehicle must go in it.

Worlds are read from files by :mod:`agent.sim.world_file` and built in code by
:func:`world_from_obstacles`, with the same checks (:mod:`agent.sim.world_checks`); rays are
cast into them by :mod:`agent.sim.raycast`.

Obstacles are identified by their *id*: their position in the ``obstacles`` of the world that
was parsed or built (walls first, then boxes, then cylinders, each in file order). A world cut
down by :meth:`World.nearby` keeps the ids of its parent, so ray hits in the small world name
the same obstacles as in the full one. Movers are numbered after every static obstacle: mover
``j`` has the id :attr:`World.mover_id_base` ``+ j`` (the number of static obstacles, kept
by :meth:`World.nearby`), so the simulator's truth can say which samples hit which mover.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from agent.sim.movers import Mover
from agent.sim.world_checks import WorldChecker, show_value
from agent.task import Task

__all__ = [
    "Obstacle",
    "ObstacleKind",
    "World",
    "assemble_world",
    "world_from_obstacles",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
ObstacleKind = Literal["wall", "box", "cylinder"]
Point = tuple[float, float]
Pose = tuple[float, float, float]


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
        :attr:`~agent.sim.raycast.RayHits.obstacle` hold for it.
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
    :func:`~agent.sim.world_file.load_world`, :func:`~agent.sim.world_file.parse_world` or
    :func:`world_from_obstacles` rather than by hand: those fill both the arrays and the
    matching :attr:`obstacles`.

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
    movers
        Moving cylinders, in file order (not culled by :meth:`nearby`: they move).
    mover_id_base
        The id of the first mover (mover ``j`` is ``mover_id_base + j``); -1, the default,
        means the number of :attr:`obstacles`. It must exceed every obstacle's id.
    task
        What the vehicle must do in this world (a world file's ``[task]``), or ``None``.
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
    movers: tuple[Mover, ...] = ()
    mover_id_base: int = -1
    task: Task | None = None
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
        movers = tuple(self.movers)
        if not all(isinstance(m, Mover) for m in movers):
            raise ValueError("World.movers must hold Mover instances")
        object.__setattr__(self, "movers", movers)
        base = int(self.mover_id_base)
        base = len(obstacles) if base == -1 else base
        if base < 0 or (ids.size and base <= int(ids.max())):
            raise ValueError(f"World.mover_id_base must exceed every obstacle id, got {base}")
        object.__setattr__(self, "mover_id_base", base)
        if self.task is not None and not isinstance(self.task, Task):
            raise ValueError(f"World.task must be a Task or None, got {type(self.task).__name__}")
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
        movers: Iterable[Mover | tuple[npt.ArrayLike, float, float, float]] = (),
        task: Task | None = None,
    ) -> World:
        """Same as :func:`world_from_obstacles`."""
        return world_from_obstacles(walls, boxes, cylinders, vehicle_pose, name, movers, task)

    @property
    def n_obstacles(self) -> int:
        """Number of obstacles in :attr:`obstacles`."""
        return len(self.obstacles)

    @property
    def n_movers(self) -> int:
        """Number of :attr:`movers`."""
        return len(self.movers)

    @property
    def mover_ids(self) -> IntArray:
        """(m,) int64: the obstacle id of each mover (in ray hits and scan truth)."""
        return np.arange(self.mover_id_base, self.mover_id_base + len(self.movers))

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
            movers=self.movers,
            mover_id_base=self.mover_id_base,
            task=self.task,
        )


# --------------------------------------------------------------------------------------------
# Building worlds
# --------------------------------------------------------------------------------------------


def _box_corners(center: Point, size: Point, yaw_rad: float) -> tuple[Point, ...]:
    """Four corners of a box, counter-clockwise from (+length/2, -width/2) in its own frame."""
    hl, hw = 0.5 * size[0], 0.5 * size[1]
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    local = ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))
    return tuple((center[0] + cy * lx - sy * ly, center[1] + sy * lx + cy * ly) for lx, ly in local)


def assemble_world(
    walls: Sequence[tuple[tuple[Point, ...], float]],
    boxes: Sequence[tuple[Point, Point, float, float]],
    cylinders: Sequence[tuple[Point, float, float]],
    vehicle_pose: Pose,
    name: str,
    movers: Sequence[Mover] = (),
    task: Task | None = None,
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
        movers=tuple(movers),
        task=task,
    )


def world_from_obstacles(
    walls: Iterable[tuple[npt.ArrayLike, float]] = (),
    boxes: Iterable[tuple[npt.ArrayLike, npt.ArrayLike, float, float]] = (),
    cylinders: Iterable[tuple[npt.ArrayLike, float, float]] = (),
    vehicle_pose: npt.ArrayLike = (0.0, 0.0, 0.0),
    name: str = "",
    movers: Iterable[Mover | tuple[npt.ArrayLike, float, float, float]] = (),
    task: Task | None = None,
) -> World:
    """Build a world in code, with the same checks on each value as a world file.

    The limits a world file is also held to (counts, magnitudes, walls that meet themselves;
    see :mod:`agent.sim.world_checks`) are for input from outside: code is trusted with any
    finite geometry.

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
    movers
        :class:`~agent.sim.movers.Mover` instances, or ``(path, radius, speed_m_s,
        reflectivity)`` per mover: ``path`` (p, 2) metres, walked back and forth.
    task
        The world's task (:class:`~agent.task.Task`, already checked), or ``None``.

    Returns
    -------
    World
        Obstacle ids: walls first, then boxes, then cylinders, each in the order given.

    Raises
    ------
    WorldFileError
        With no path, naming the entry as a world file would (``[[box]] 2: ...``).
    """
    chk = WorldChecker(None)

    def plain(value: Any) -> Any:
        """``value`` with numpy arrays, at any depth, turned into lists."""
        if isinstance(value, np.ndarray):
            return value.tolist()
        if isinstance(value, list | tuple):
            return [plain(v) for v in value]
        return value

    def unpack(entry: Any, n: int, where: str, fields: str) -> tuple[Any, ...]:
        if not isinstance(entry, Sequence) or isinstance(entry, str) or len(entry) != n:
            chk.fail(where, f"must be a tuple {fields}, got {show_value(entry)}")
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
        chk.fail("name", f"must be a string, got {show_value(name)}")
    mover_list: list[Mover] = []
    for i, mover in enumerate(movers):
        where = f"[[mover]] {i + 1}"
        if isinstance(mover, Mover):
            mover_list.append(mover)
            continue
        path, radius, speed, refl = unpack(
            mover, 4, where, "(path, radius, speed_m_s, reflectivity)"
        )
        table = {"path": path, "radius": radius, "speed": speed}
        pts, r, v = chk.mover(table, where, file_limits=False)
        mover_list.append(Mover(r, chk.positive(refl, where, "reflectivity"), pts, v))
    if task is not None and not isinstance(task, Task):
        chk.fail("task", f"must be a Task or None, got {show_value(task)}")
    return assemble_world(
        wall_list, box_list, cyl_list, (pose[0], pose[1], pose[2]), name, mover_list, task
    )
