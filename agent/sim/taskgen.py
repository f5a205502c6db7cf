"""Random worlds with a task each: the closed-loop evaluation's runs.

Frames follow REP-103 (x forward, y left, angles counter-clockwise); metres, seconds,
radians; world frame.

Every world is drawn only from the ``rng`` it is given, in a fixed order (layout, task kind,
then per attempt: the static world, the start, the goal or docking plate, the start's
heading, the movers), so the same generator state gives the same world; run ``i`` of
:func:`random_tasks` has its own generator, ``numpy.random.default_rng([seed, i])``, so any
run can be drawn again alone and shards of a run list hold identical worlds.

Layouts (at most 14 m × 12 m, at most :data:`MAX_PRIMITIVES` static segments and circles,
the docking plate included):

* ``"office"``: a rectangle of 10-14 m × 8-12 m crossed by a corridor 1.6-2.4 m wide, with
  2-3 rooms of at least 3 m on each side behind partitions, each room with one doorway
  1.1-1.8 m wide onto the corridor (its edges the partition's end faces,
  :data:`PARTITION_THICKNESS_M` across); 0-2 furniture boxes (0.6-1.8 m × 0.4-0.8 m) against the
  walls of each room (not within 1 m of its doorway's wall), 1-3 pillars (radius 0.1-0.25 m)
  in the rooms;
* ``"cluttered"``: a hall of 8-14 m × 6-12 m with 8-20 boxes (sides 0.2-1.0 m, any heading)
  and cylinders (radius 0.1-0.4 m) scattered in it, 0.1 m apart (boxes turn into cylinders
  once the primitive budget is spent).

Walls, boxes and cylinders reflect 0.3-2.0 (below the docking threshold of 2.5); movers too.

Tasks (kind uniform over goto, park, dock unless given):

* the start: a place where the vehicle can turn on the spot with :data:`START_CLEARANCE_M`
  to spare (its circumcircle that far from everything), facing the first leg of its route
  to within 45°;
* ``goto``, ``park``: a goal whose circumcircle is clear by :data:`GOAL_CLEARANCE_M`,
  5-12 m away along the shortest path on which the vehicle can turn anywhere
  (:func:`agent.sim.paths.turning_radius_m`); park adds a heading, uniform;
* ``dock``: a docking plate (a box 0.02 m × 0.3-0.5 m, reflectivity 3.0-5.0) 1-2 cm in front
  of a wall; the docking pose (the head's centre of scanning :data:`DOCK_DISTANCE_M` in
  front of the plate's face, square to it) is as clear as a goal and 5-12 m away; the
  goal is the plate's centre give or take 3 cm, as a dock database would hold it.
  Tolerance :data:`DOCK_TOLERANCE_M`.

Every task is checked solvable against the true static world: the path above exists from
the start to the goal (for dock, to the docking pose) in the finished world. Its time limit
is ``4 · length / 0.5 m/s + 30 s``, rounded up to a second.

0-3 movers (radius 0.15-0.3 m, 0.2-0.8 m/s) walk straight paths of 1-5 m (cut to the outer
walls) that cross the route at 45-135° in its middle 60 %; they walk blindly, through
obstacles, but never within :data:`MOVER_CLEARANCE_M` of the vehicle's circumcircle at the
start or at the goal pose, nor within :data:`agent.sim.movers.MOVER_GAP_M` of one another
within the task's time limit (walks that would are drawn again, at most 50 times, then dropped).

A world that admits no such task is drawn again, at most :data:`MAX_ATTEMPTS` times, then
:class:`ValueError` is raised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from agent.arrays import FloatArray
from agent.kinematics.vehicle import VehicleSpec
from agent.sim.movers import Mover, walks_apart
from agent.sim.paths import (
    CELL_M,
    ClearanceGrid,
    PathField,
    clearance_grid,
    path_field,
    point_clearance,
    turning_radius_m,
)
from agent.sim.world import World
from agent.sim.worldgen import _segment_distance
from agent.task import TASK_KINDS, Task, TaskKind

__all__ = [
    "DOCK_DISTANCE_M",
    "DOCK_TOLERANCE_M",
    "GOAL_CLEARANCE_M",
    "LAYOUTS",
    "MAX_ATTEMPTS",
    "MAX_PRIMITIVES",
    "MOVER_CLEARANCE_M",
    "PATH_LENGTH_M",
    "START_CLEARANCE_M",
    "Layout",
    "random_tasks",
    "task_world",
    "time_limit_s",
]

Layout = Literal["office", "cluttered"]
LAYOUTS: tuple[Layout, ...] = ("office", "cluttered")

MAX_PRIMITIVES = 60
"""Most static segments plus circles in a world: the simulator casts every beam at each."""
START_CLEARANCE_M = 0.42
"""The outline's least clearance at the start pose, at any heading (its circumcircle's, 0.5 m,
clear to 0.92 m from the centre): the ring the sensor cannot see from the start, 0.85 m (the
0.3 m head offset, the 0.4 m near limit and the far profile's 0.15 m gap), plus the cells'
half-diagonals. The controller is told as much (``ControllerSettings.start_clear_m``)."""
GOAL_CLEARANCE_M = 0.15
"""The outline's least clearance at the goal pose (for dock, the docking pose)."""
PATH_LENGTH_M = (5.0, 12.0)
"""The goal's distance from the start along the shortest path, metres."""
MOVER_CLEARANCE_M = 1.0
"""Least distance from a mover's walk to the vehicle's circumcircle at the start and the
goal pose: no run fails at its first instant, nor while the vehicle waits at the goal."""
DOCK_DISTANCE_M = 0.5
DOCK_TOLERANCE_M = 0.1
"""A dock task's success radius for the head's centre of scanning (goto and park keep the
task's default, 0.3 m)."""
MAX_ATTEMPTS = 30
"""Worlds drawn for one task before giving up (measured: about 1.1 on average)."""

_REFLECTIVITY = (0.3, 2.0)
_PLATE_REFLECTIVITY = (3.0, 5.0)
_PLATE_WIDTH_M = (0.3, 0.5)
_PLATE_THICKNESS_M = 0.02
PARTITION_THICKNESS_M = 0.1
"""A partition's thickness, shown only where it matters: a wall is its centre line, and each
end at a doorway has its face, a segment this long across it. A wall of no thickness seen
end-on returns nothing, which no real wall does: beams along a doorway's edge then vouched
for space through the wall's end, and the vehicle, turning through the doorway, struck it
(measured: random run 10 of seed 0, ``active``). The long faces stand at the centre line,
each 5 cm from where a real partition's would be; four segments a partition instead of two
would spend the primitive budget the simulator casts every beam at."""
_PLATE_GAP_M = (0.01, 0.02)
_GOAL_ERROR_M = 0.03
_PLATE_CANDIDATES = 40
_PICKS = 10  # goal (or start) cells tried in one world before drawing the next
_MOVER_TRIES = 50

Point = tuple[float, float]


@dataclass
class _Plan:
    """A static world being drawn: its entries and the outer walls' rectangle."""

    lo: FloatArray
    hi: FloatArray
    walls: list[tuple[tuple[Point, ...], float]] = field(default_factory=list)
    boxes: list[tuple[Point, Point, float, float]] = field(default_factory=list)
    cylinders: list[tuple[Point, float, float]] = field(default_factory=list)

    @property
    def primitives(self) -> int:
        return sum(len(p) - 1 for p, _ in self.walls) + 4 * len(self.boxes) + len(self.cylinders)

    def world(
        self,
        plate: tuple[Point, Point, float, float] | None = None,
        pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
        name: str = "",
        movers: tuple[Mover, ...] = (),
        task: Task | None = None,
    ) -> World:
        boxes = [*self.boxes, plate] if plate is not None else self.boxes
        return World.build(self.walls, boxes, self.cylinders, pose, name, movers, task)


def _refl(rng: np.random.Generator) -> float:
    return float(rng.uniform(*_REFLECTIVITY))


def _rectangle(lo: FloatArray, hi: FloatArray) -> tuple[Point, ...]:
    x0, y0, x1, y1 = float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])
    return ((x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0))


def _office(rng: np.random.Generator) -> _Plan:
    """Rooms either side of a corridor (module docstring)."""
    width, height = float(rng.uniform(10.0, 14.0)), float(rng.uniform(8.0, 12.0))
    corridor = float(rng.uniform(1.6, 2.4))
    y_south = float(rng.uniform(2.8, height - corridor - 2.8))
    plan = _Plan(np.zeros(2), np.array([width, height]))
    plan.walls.append((_rectangle(plan.lo, plan.hi), _refl(rng)))
    rooms: list[tuple[float, float, float, float]] = []  # x0, x1, far wall's y, corridor's y
    for y_wall, y_far in ((y_south, 0.0), (y_south + corridor, height)):
        n = int(rng.integers(2, 4))
        edges = np.concatenate(
            [[0.0], np.cumsum(3.0 + rng.dirichlet(np.ones(n)) * (width - 3 * n))]
        )
        edges[-1] = width
        refl = _refl(rng)
        cursor = 0.0
        for k in range(n):
            door = float(rng.uniform(1.1, 1.8))
            left = float(rng.uniform(edges[k] + 0.3, edges[k + 1] - 0.3 - door))
            plan.walls.append((((cursor, y_wall), (left, y_wall)), refl))
            cursor = left + door
            half = 0.5 * PARTITION_THICKNESS_M
            for edge in (left, cursor):  # the doorway's edges: the partition's end faces
                plan.walls.append((((edge, y_wall - half), (edge, y_wall + half)), refl))
            rooms.append((float(edges[k]), float(edges[k + 1]), y_far, y_wall))
        plan.walls.append((((cursor, y_wall), (width, y_wall)), refl))
        for x in edges[1:-1]:
            plan.walls.append((((float(x), y_far), (float(x), y_wall)), refl))
    n_pillars = int(rng.integers(1, 4))
    budget = MAX_PRIMITIVES - plan.primitives - n_pillars - 4  # 4: a docking plate's faces
    placed: list[FloatArray] = []  # (2, 2) axis-aligned extents [lo, hi] of the furniture
    for x0, x1, y_far, y_wall in rooms:
        inward = 1.0 if y_wall > y_far else -1.0
        for _ in range(int(rng.integers(0, 3))):
            if budget < 4:
                break
            for _attempt in range(20):
                which = int(rng.integers(0, 3))  # far wall, left wall, right wall
                length, depth = float(rng.uniform(0.6, 1.8)), float(rng.uniform(0.4, 0.8))
                off = float(rng.uniform(0.02, 0.08)) + 0.5 * depth
                u = float(rng.random())
                if which == 0:
                    span = (x0 + 0.05 + 0.5 * length, x1 - 0.05 - 0.5 * length)
                    centre = (span[0] + u * (span[1] - span[0]), y_far + inward * off)
                    size = (length, depth)
                else:
                    near = y_wall - inward * (1.0 + 0.5 * length)
                    far = y_far + inward * (0.05 + 0.5 * length)
                    span = (far, near) if inward > 0 else (near, far)
                    x = x0 + off if which == 1 else x1 - off
                    centre = (x, span[0] + u * (span[1] - span[0]))
                    size = (depth, length)
                extent = np.array([centre, centre]) + 0.5 * np.array([size]) * [[-1], [1]]
                if span[0] > span[1] or any(
                    np.all(extent[0] < p[1] + 0.1) and np.all(p[0] < extent[1] + 0.1)
                    for p in placed
                ):
                    continue
                placed.append(extent)
                plan.boxes.append((centre, size, 0.0, _refl(rng)))
                budget -= 4
                break
    for _ in range(n_pillars):
        for _attempt in range(20):
            x0, x1, y_far, y_wall = rooms[int(rng.integers(0, len(rooms)))]
            radius = float(rng.uniform(0.1, 0.25))
            lo = np.array([x0, min(y_far, y_wall)]) + 0.6 + radius
            hi = np.array([x1, max(y_far, y_wall)]) - 0.6 - radius
            at = lo + rng.random(2) * (hi - lo)
            refl = _refl(rng)
            if np.any(lo > hi) or any(
                np.all(at > p[0] - radius - 0.3) and np.all(at < p[1] + radius + 0.3)
                for p in placed
            ):
                continue
            plan.cylinders.append(((float(at[0]), float(at[1])), radius, refl))
            break
    return plan


def _cluttered(rng: np.random.Generator) -> _Plan:
    """An open hall with boxes and cylinders scattered in it (module docstring)."""
    size_xy = np.array([rng.uniform(8.0, 14.0), rng.uniform(6.0, 12.0)])
    plan = _Plan(np.zeros(2), size_xy)
    plan.walls.append((_rectangle(plan.lo, plan.hi), _refl(rng)))
    budget = MAX_PRIMITIVES - plan.primitives - 4  # 4: a docking plate's faces
    n = int(rng.integers(8, 21))
    placed: list[tuple[FloatArray, float]] = []  # bounding circles
    for k in range(n):
        for _attempt in range(50):
            is_box = bool(rng.random() < 0.5)
            centre = plan.lo + 0.4 + rng.random(2) * (size_xy - 0.8)
            sides = rng.uniform(0.2, 1.0, 2)
            yaw = float(rng.uniform(0.0, math.pi))
            radius = float(rng.uniform(0.1, 0.4))
            refl = _refl(rng)
            # Every object left to place must still fit: a box takes 4 primitives, a
            # cylinder 1.
            is_box = is_box and budget - 4 >= n - k - 1
            bound = 0.5 * float(np.hypot(*sides)) if is_box else radius
            if np.any(centre - bound < plan.lo + 0.1) or np.any(centre + bound > plan.hi - 0.1):
                continue
            if any(float(np.hypot(*(centre - c))) < bound + r + 0.1 for c, r in placed):
                continue
            xy = (float(centre[0]), float(centre[1]))
            if is_box:
                plan.boxes.append((xy, (float(sides[0]), float(sides[1])), yaw, refl))
                budget -= 4
            else:
                plan.cylinders.append((xy, radius, refl))
                budget -= 1
            placed.append((centre, bound))
            break
    return plan


def time_limit_s(path_length_m: float) -> float:
    """A task's time limit: four times the path at 0.5 m/s, plus 30 s, rounded up."""
    return float(math.ceil(4.0 * path_length_m / 0.5 + 30.0))


def _clear_cells(grid: ClearanceGrid, plan: _Plan, need_m: float) -> FloatArray:
    """Centres (n, 2) of the cells inside the outer walls whose grid clearance is at least
    ``need_m`` plus a cell (most of the grid's error: the exact check follows)."""
    flat = np.flatnonzero(grid.clearance_m >= need_m + grid.cell_m)
    centres = grid.centres(*np.divmod(flat, grid.shape[1]))
    inside = np.all((centres > plan.lo) & (centres < plan.hi), axis=1)
    return np.asarray(centres[inside], dtype=np.float64)


def _pick(
    rng: np.random.Generator, candidates: FloatArray, world: World, need_m: float, cell_m: float
) -> FloatArray | None:
    """A point near one of ``candidates`` (n, 2) (jittered within its cell) whose exact
    clearance is at least ``need_m``; ``None`` after :data:`_PICKS` tries or none at all."""
    for _ in range(_PICKS if candidates.shape[0] else 0):
        xy = candidates[int(rng.integers(0, candidates.shape[0]))] + rng.uniform(
            -0.45 * cell_m, 0.45 * cell_m, 2
        )
        if float(point_clearance(world, xy)[0]) >= need_m:
            return np.asarray(xy, dtype=np.float64)
    return None


def _plate(
    rng: np.random.Generator,
    plan: _Plan,
    world: World,
    field_: PathField,
    need_m: float,
    reach_m: float,
) -> tuple[tuple[Point, Point, float, float], FloatArray, FloatArray] | None:
    """A docking plate on a wall whose docking pose is clear and 5-12 m away: the plate
    (centre, size, yaw, reflectivity), its centre (2,) and the docking pose's base_link
    (2,), or ``None``. ``reach_m`` is the head's offset plus the docking distance."""
    width = float(rng.uniform(*_PLATE_WIDTH_M))
    refl = float(rng.uniform(*_PLATE_REFLECTIVITY))
    wall_ids = [o.id for o in world.obstacles if o.kind == "wall"]
    on_wall = np.isin(world.segments_obstacle, wall_ids)
    a, b = world.segments_start[on_wall], world.segments_end[on_wall]
    length = np.hypot(*(b - a).T)
    usable = np.maximum(length - width - 0.1, 0.0)
    k = _PLATE_CANDIDATES
    seg = rng.choice(length.size, size=k, p=usable / usable.sum())
    along = 0.05 + 0.5 * width + rng.random(k) * usable[seg]
    side = rng.choice([-1.0, 1.0], size=k)
    gap = rng.uniform(*_PLATE_GAP_M, size=k)
    u = (b - a)[seg] / length[seg, None]
    normal = side[:, None] * np.stack([-u[:, 1], u[:, 0]], axis=1)
    on = a[seg] + along[:, None] * u
    centre = on + (gap + 0.5 * _PLATE_THICKNESS_M)[:, None] * normal
    face = on + (gap + _PLATE_THICKNESS_M)[:, None] * normal
    base = face + reach_m * normal
    i, j, inside = field_.grid.cells(base)
    distance = field_.distance_m[i, j]
    # A clear docking pose also keeps the plate off any box, pillar or corner: anything
    # over the plate lies within 0.5 m of the pose, well inside its clearance.
    ok = (
        inside
        & (distance >= PATH_LENGTH_M[0] + 0.2)
        & (distance <= PATH_LENGTH_M[1])
        & (field_.grid.clearance_m[i, j] >= need_m + field_.grid.cell_m)
        & (point_clearance(world, base) >= need_m)
    )
    if not np.any(ok):
        return None
    c = int(np.flatnonzero(ok)[0])
    yaw = math.atan2(float(normal[c, 1]), float(normal[c, 0]))
    box = ((float(centre[c, 0]), float(centre[c, 1])), (_PLATE_THICKNESS_M, width), yaw, refl)
    return box, centre[c], base[c]


def _movers(
    rng: np.random.Generator,
    plan: _Plan,
    route: FloatArray,
    ends: FloatArray,
    keep_off_m: float,
    horizon_s: float,
) -> tuple[Mover, ...]:
    """0-3 movers crossing ``route`` (k, 2) whose walks stay ``keep_off_m`` plus their
    radius from the points ``ends`` (2, 2) (the start and the goal pose), and
    :data:`agent.sim.movers.MOVER_GAP_M` from one another for ``horizon_s`` (the task's
    time limit; :func:`agent.sim.movers.walks_apart`)."""
    steps = np.diff(route, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*steps.T))])
    movers: list[Mover] = []
    for _ in range(int(rng.integers(0, 4))):
        for _attempt in range(_MOVER_TRIES):
            s = float(rng.uniform(0.2, 0.8)) * arc[-1]
            crossing = rng.uniform(math.pi / 4, 3 * math.pi / 4) * rng.choice([-1.0, 1.0])
            length = float(rng.uniform(2.0, 5.0))
            share = float(rng.uniform(0.3, 0.7))  # where along its walk it crosses
            radius = float(rng.uniform(0.15, 0.3))
            speed = float(rng.uniform(0.2, 0.8))
            refl = _refl(rng)
            leg = min(int(np.searchsorted(arc, s, side="right")) - 1, steps.shape[0] - 1)
            along = steps[leg] / np.hypot(*steps[leg])
            point = route[leg] + (s - arc[leg]) * along
            heading = math.atan2(along[1], along[0]) + float(crossing)
            u = np.array([math.cos(heading), math.sin(heading)])
            # The walk, cut to the outer walls less the mover's radius and 5 cm.
            lo, hi = plan.lo + radius + 0.05, plan.hi - radius - 0.05
            with np.errstate(divide="ignore", invalid="ignore"):
                t_a, t_b = (lo - point) / u, (hi - point) / u
            t0 = max(-share * length, *np.minimum(t_a, t_b)[u != 0.0])
            t1 = min((1.0 - share) * length, *np.maximum(t_a, t_b)[u != 0.0])
            if t1 - t0 < 1.0:
                continue
            walk = np.stack([point + t0 * u, point + t1 * u])
            if float(_segment_distance(ends, walk[0], walk[1]).min()) < keep_off_m + radius:
                continue
            mover = Mover(radius, refl, walk, speed)
            if not walks_apart(movers, mover, horizon_s=horizon_s):
                continue
            movers.append(mover)
            break
    return tuple(movers)


def _attempt(
    rng: np.random.Generator, kind: TaskKind, layout: Layout, spec: VehicleSpec
) -> tuple[World, Task] | None:
    """One draw of a world and its task; ``None`` if it admits none."""
    plan = _office(rng) if layout == "office" else _cluttered(rng)
    static = plan.world()
    grid = clearance_grid(static, CELL_M, pad_m=0.5)
    radius = turning_radius_m(spec)
    start_need = spec.circumradius_m + START_CLEARANCE_M
    start = _pick(rng, _clear_cells(grid, plan, start_need), static, start_need, grid.cell_m)
    need = spec.circumradius_m + GOAL_CLEARANCE_M
    cells = _clear_cells(grid, plan, need)
    if start is None:
        return None
    field_ = path_field(grid, start, radius, limit_m=PATH_LENGTH_M[1] + 0.5)
    plate = None
    if kind == "dock":
        found = _plate(rng, plan, static, field_, need, spec.head_offset_m + DOCK_DISTANCE_M)
        if found is None:
            return None
        plate, plate_centre, goal = found
    else:
        i, j, _ = grid.cells(cells)
        far = field_.distance_m[i, j]
        ok = (far >= PATH_LENGTH_M[0] + 0.2) & (far <= PATH_LENGTH_M[1])
        picked = _pick(rng, cells[ok], static, need, grid.cell_m)
        if picked is None:
            return None
        goal = picked
    goal_yaw = float(rng.uniform(-math.pi, math.pi)) if kind == "park" else None
    # The check on the finished static world (the plate included).
    final = plan.world(plate)
    if plate is not None:
        final_grid = clearance_grid(final, CELL_M, pad_m=0.5)
        field_ = path_field(final_grid, start, radius, limit_m=PATH_LENGTH_M[1] + 0.5)
    route = field_.path_to(goal)
    if not PATH_LENGTH_M[0] <= route.length_m <= PATH_LENGTH_M[1]:
        return None
    first = route.waypoints[1] - route.waypoints[0]
    yaw = math.atan2(first[1], first[0]) + float(rng.uniform(-math.pi / 4, math.pi / 4))
    yaw = math.remainder(yaw, 2.0 * math.pi)
    limit = time_limit_s(route.length_m)
    movers = _movers(
        rng, plan, route.waypoints, np.stack([start, goal]),
        spec.circumradius_m + MOVER_CLEARANCE_M, limit,
    )  # fmt: skip
    if kind == "dock":
        error = rng.uniform(-_GOAL_ERROR_M, _GOAL_ERROR_M, 2)
        near = plate_centre + error
        task = Task(
            "dock",
            (float(near[0]), float(near[1])),
            tolerance_m=DOCK_TOLERANCE_M,
            time_limit_s=limit,
            dock_distance_m=DOCK_DISTANCE_M,
        )
    else:
        task = Task(kind, (float(goal[0]), float(goal[1])), goal_yaw, time_limit_s=limit)
    name = f"{layout} {kind}, {len(movers)} mover{'' if len(movers) == 1 else 's'}"
    pose = (float(start[0]), float(start[1]), yaw)
    return plan.world(plate, pose, name, movers, task), task


def task_world(
    rng: np.random.Generator,
    kind: TaskKind | None = None,
    layout: Layout | None = None,
    vehicle: VehicleSpec | None = None,
) -> tuple[World, Task]:
    """Draw a world and a solvable task in it (module docstring).

    Parameters
    ----------
    rng
        The only source of randomness, drawn from in a fixed order.
    kind
        ``"goto"``, ``"park"`` or ``"dock"``; drawn uniformly if ``None``.
    layout
        ``"office"`` or ``"cluttered"``; drawn uniformly if ``None``.
    vehicle
        The outline and head offset (default :class:`VehicleSpec` ``()``).

    Returns
    -------
    world, task
        The world (its :attr:`~agent.sim.world.World.task` is ``task``, its ``vehicle_pose``
        the start) and the task.

    Raises
    ------
    ValueError
        For an unknown kind or layout, or when :data:`MAX_ATTEMPTS` worlds admit no task.
    """
    if kind is not None and kind not in TASK_KINDS:
        raise ValueError(f"kind must be one of {', '.join(TASK_KINDS)}, got {kind!r}")
    if layout is not None and layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    spec = vehicle if vehicle is not None else VehicleSpec()
    chosen_layout = layout if layout is not None else LAYOUTS[int(rng.integers(0, len(LAYOUTS)))]
    chosen_kind = kind if kind is not None else TASK_KINDS[int(rng.integers(0, len(TASK_KINDS)))]
    for _ in range(MAX_ATTEMPTS):
        drawn = _attempt(rng, chosen_kind, chosen_layout, spec)
        if drawn is not None:
            return drawn
    raise ValueError(
        f"task_world: no solvable {chosen_kind} task in {MAX_ATTEMPTS} {chosen_layout} worlds"
    )


def random_tasks(n: int, seed: int) -> list[tuple[World, Task]]:
    """``n`` worlds with tasks; run ``i`` is ``task_world(numpy.random.default_rng([seed,
    i]))``, so each can be drawn again alone.

    Raises
    ------
    ValueError
        For a negative ``n`` or ``seed``.
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    if seed < 0:
        raise ValueError(f"seed must be >= 0, got {seed}")
    return [task_world(np.random.default_rng([seed, i])) for i in range(n)]
