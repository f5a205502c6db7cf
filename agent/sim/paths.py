"""Shortest collision-free paths of a disc through a world's static obstacles, on a grid.

Frames follow REP-103 (x forward, y left); metres, world frame. Movers are ignored: these
are paths through the *static* world (the task generator's solvability check, and the
reference path a closed-loop run is scored against).

**The clearance grid** (:func:`clearance_grid`). Square cells of side ``h`` (``cell_m``,
5 cm by default) cover the world's bounds. Every wall piece, box face and cylinder outline
is sampled at most ``h/2`` apart and the cells holding a sample are marked occupied; boxes
and cylinders are solid, their outlines filled (``scipy.ndimage.binary_fill_holes``), walls
are not (a closed wall is a room's outline). ``scipy.ndimage.distance_transform_edt`` gives
each cell centre its distance ``e`` to the nearest occupied cell centre. With ``d`` the true
distance from the centre to the nearest surface, every surface point lies within ``h/4`` of
a sample and every sample within ``h/√2`` of its cell's centre, so

    e − (h/4 + h/√2) ≤ d ≤ e + h/√2            (at h = 5 cm: −4.8 cm, +3.5 cm).

**The path** (:func:`path_field`, :func:`shortest_path`). A disc of radius ``r`` may stand
on the cells with ``e ≥ r``. scipy's Dijkstra (``scipy.sparse.csgraph.dijkstra``) runs over
those cells with 16 neighbours (the 8 adjacent and the 8 a knight's move away; a diagonal
or knight's step needs the cells it passes between to be free too). The 16 step directions
are at most 26.6° apart, so a grid path is at most ``1/cos(13.3°) − 1`` = 2.8 % longer than
the straight line it follows. The grid path is then pulled straight: from each waypoint the
farthest later one in sight (the segment sampled ``h/4`` apart, every sample's cell free) is
taken next. Where start and goal see each other the length is the exact straight line;
elsewhere it lies between the true shortest path among the free cells and the grid's.

Two radii matter for a rectangular vehicle (:class:`~agent.kinematics.vehicle.VehicleSpec`):

* :func:`reference_radius_m`: the inradius less ``√2·h`` (the free cells then include every
  cell whose centre is within ``h/√2`` of a place the inradius disc truly fits): no path the
  rectangle can drive is shorter than this disc's, so its length is a lower bound (up to the
  grid's 2.8 % before pulling straight);
* :func:`turning_radius_m`: the circumradius plus :data:`TURN_MARGIN_M` (0.1 m): along such a
  path every point lies within ``h/8 + h/√2`` of a free cell centre, whose true clearance is
  at least ``r − h/4 − h/√2``, so the true clearance is at least ``r − 1.8·h`` (0.09 m at
  5 cm) and the vehicle can turn on the spot anywhere along it.

Cost, measured on 60 of the task generator's worlds (64 000 cells of 5 cm on average): the
grid 6 ms, Dijkstra from one start over every free cell 37 ms (graph included), the path
pulled straight 4 ms; :func:`shortest_path` 40 ms in all, 60 ms at most.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage
from scipy.sparse import csr_array
from scipy.sparse.csgraph import dijkstra

from agent.arrays import BoolArray, FloatArray
from agent.kinematics.vehicle import VehicleSpec
from agent.sim.world import World

__all__ = [
    "CELL_M",
    "TURN_MARGIN_M",
    "ClearanceGrid",
    "PathField",
    "PathResult",
    "clearance_grid",
    "path_field",
    "point_clearance",
    "reference_radius_m",
    "shortest_path",
    "turning_radius_m",
]

IntArray = npt.NDArray[np.int64]

CELL_M = 0.05
"""Default cell side, metres."""
TURN_MARGIN_M = 0.1
"""Added to the circumradius for paths the vehicle can turn on the spot anywhere along:
more than the grid's worst clearance error along a path (``1.8·h`` = 0.09 m at 5 cm)."""
MAX_CELLS = 4_000_000
"""Largest grid built (about 100 m × 100 m at 5 cm): the arrays stay within ~100 MB."""

# Half of the 16-neighbourhood, (d_row, d_col), each with the cells a step passes between
# (the graph is undirected: Dijkstra with directed=False takes each step both ways).
_STEPS: tuple[tuple[tuple[int, int], tuple[tuple[int, int], ...]], ...] = (
    ((0, 1), ()),
    ((1, 0), ()),
    ((1, 1), ((0, 1), (1, 0))),
    ((1, -1), ((0, -1), (1, 0))),
    ((1, 2), ((0, 1), (1, 1))),
    ((2, 1), ((1, 0), (1, 1))),
    ((1, -2), ((0, -1), (1, -1))),
    ((2, -1), ((1, 0), (1, -1))),
)


def reference_radius_m(vehicle: VehicleSpec | None = None, cell_m: float = CELL_M) -> float:
    """The disc radius for a lower bound on any path the vehicle drives: its inradius less
    ``√2·cell_m`` (module docstring)."""
    spec = vehicle if vehicle is not None else VehicleSpec()
    return spec.inradius_m - math.sqrt(2.0) * cell_m


def turning_radius_m(vehicle: VehicleSpec | None = None, margin_m: float = TURN_MARGIN_M) -> float:
    """The disc radius for a path the vehicle can turn on the spot anywhere along: its
    circumradius plus ``margin_m`` (module docstring)."""
    spec = vehicle if vehicle is not None else VehicleSpec()
    return spec.circumradius_m + margin_m


# --------------------------------------------------------------------------------------------
# Exact clearance of points
# --------------------------------------------------------------------------------------------


def point_clearance(world: World, xy: npt.ArrayLike) -> FloatArray:
    """Exact distance from points to the nearest static surface.

    Parameters
    ----------
    world
        Its static segments and circles (boxes are their four faces: a point inside a box
        gets its distance to the faces).
    xy
        (n, 2) or (2,) points, metres, world frame.

    Returns
    -------
    FloatArray
        (n,) metres, >= 0 (``inf`` in a world with nothing in it); a point inside a cylinder
        gets 0.
    """
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if not np.all(np.isfinite(p)):
        raise ValueError("point_clearance: points must be finite")
    out = np.full(p.shape[0], np.inf)
    a, b = world.segments_start, world.segments_end
    if a.shape[0]:
        e = b - a  # (m, 2)
        rel = p[:, None, :] - a[None, :, :]  # (n, m, 2)
        length2 = np.maximum(np.einsum("mj,mj->m", e, e), 1e-300)
        t = np.clip(np.einsum("nmj,mj->nm", rel, e) / length2, 0.0, 1.0)
        gap = rel - t[:, :, None] * e[None, :, :]
        out = np.minimum(out, np.hypot(gap[..., 0], gap[..., 1]).min(axis=1))
    if world.circles_radius.size:
        rel = p[:, None, :] - world.circles_center[None, :, :]
        d = np.hypot(rel[..., 0], rel[..., 1]) - world.circles_radius[None, :]
        out = np.minimum(out, np.maximum(d, 0.0).min(axis=1))
    return out


# --------------------------------------------------------------------------------------------
# The clearance grid
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ClearanceGrid:
    """Each cell centre's distance to the nearest static surface (module docstring).

    Attributes
    ----------
    origin_xy
        (2,) float64, metres, world frame: the centre of cell ``[0, 0]``.
    cell_m
        Cell side, metres.
    clearance_m
        (rows, cols) float64, metres: ``e`` of the module docstring (``inf`` with nothing in
        the world). Row ``i``, column ``j`` is centred on ``origin_xy + h·(j, i)``.
    """

    origin_xy: FloatArray
    cell_m: float
    clearance_m: FloatArray

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, cols)."""
        rows, cols = self.clearance_m.shape
        return int(rows), int(cols)

    def cells(self, xy: npt.ArrayLike) -> tuple[IntArray, IntArray, BoolArray]:
        """Row and column of the cells holding points ``xy`` (n, 2), and whether each point
        lies in the grid (the indices of points outside are clipped into it)."""
        p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        ij = np.rint((p - self.origin_xy) / self.cell_m)[:, ::-1]  # (row, col)
        rows, cols = self.shape
        inside = np.all((ij >= 0) & (ij < (rows, cols)), axis=1)
        i = np.clip(ij[:, 0], 0, rows - 1).astype(np.int64)
        j = np.clip(ij[:, 1], 0, cols - 1).astype(np.int64)
        return i, j, inside

    def centres(self, i: npt.ArrayLike, j: npt.ArrayLike) -> FloatArray:
        """(n, 2) metres: the centres of cells ``(i, j)``."""
        ij = np.stack([np.asarray(j, dtype=np.float64), np.asarray(i, dtype=np.float64)], -1)
        return np.asarray(self.origin_xy + self.cell_m * ij.reshape(-1, 2), dtype=np.float64)


def _surface_samples(world: World, spacing_m: float) -> tuple[FloatArray, BoolArray]:
    """(q, 2) points on every static segment and circle outline, at most ``spacing_m``
    apart, the ends of every segment included; and (q,) whether each lies on a box or a
    cylinder (an outline that encloses a solid) rather than on a wall."""
    pieces, solid = [np.empty((0, 2))], [np.empty(0, dtype=bool)]
    a, b = world.segments_start, world.segments_end
    if a.shape[0]:
        n = np.ceil(np.hypot(*(b - a).T) / spacing_m).astype(np.int64) + 1  # >= 1 interval
        which = np.repeat(np.arange(n.size), n)
        first = np.repeat(np.cumsum(n) - n, n)
        t = (np.arange(which.size) - first) / np.maximum(n[which] - 1, 1)
        pieces.append(a[which] + t[:, None] * (b - a)[which])
        is_box = np.array([o.kind == "box" for o in world.obstacles], dtype=bool)
        ids = np.array([o.id for o in world.obstacles], dtype=np.int64)
        box_ids = ids[is_box]
        solid.append(np.isin(world.segments_obstacle, box_ids)[which])
    r = world.circles_radius
    if r.size:
        n = np.maximum(np.ceil(2.0 * math.pi * r / spacing_m).astype(np.int64), 8)
        which = np.repeat(np.arange(n.size), n)
        first = np.repeat(np.cumsum(n) - n, n)
        angle = 2.0 * math.pi * (np.arange(which.size) - first) / n[which]
        ring = np.stack([np.cos(angle), np.sin(angle)], axis=1) * r[which, None]
        pieces.append(world.circles_center[which] + ring)
        solid.append(np.ones(which.size, dtype=bool))
    return np.concatenate(pieces), np.concatenate(solid)


def clearance_grid(
    world: World,
    cell_m: float = CELL_M,
    pad_m: float = 1.0,
    include_xy: npt.ArrayLike | None = None,
) -> ClearanceGrid:
    """Rasterise ``world``'s static obstacles and find each cell's clearance.

    Parameters
    ----------
    world
        Its static segments and circles.
    cell_m
        Cell side, metres, > 0.
    pad_m
        The grid reaches this far beyond the obstacles (and ``include_xy``), metres, >= 0.
    include_xy
        (n, 2) further points the grid must cover (a start and a goal), metres.

    Returns
    -------
    ClearanceGrid

    Raises
    ------
    ValueError
        For a non-positive cell, a negative pad, or a grid of more than :data:`MAX_CELLS`.
    """
    if not (math.isfinite(cell_m) and cell_m > 0.0):
        raise ValueError(f"cell_m must be positive and finite, got {cell_m!r}")
    if not (math.isfinite(pad_m) and pad_m >= 0.0):
        raise ValueError(f"pad_m must be >= 0 and finite, got {pad_m!r}")
    samples, solid = _surface_samples(world, 0.5 * cell_m)
    extent = [samples]
    if include_xy is not None:
        extent.append(np.asarray(include_xy, dtype=np.float64).reshape(-1, 2))
    every = np.concatenate(extent)
    if every.shape[0] == 0:
        every = np.zeros((1, 2))
    if not np.all(np.isfinite(every)):
        raise ValueError("clearance_grid: include_xy must be finite")
    lo = every.min(axis=0) - pad_m
    counts = np.ceil((every.max(axis=0) + pad_m - lo) / cell_m).astype(np.int64) + 1
    if int(counts[0]) * int(counts[1]) > MAX_CELLS:
        raise ValueError(
            f"clearance_grid: {int(counts[0])} x {int(counts[1])} cells of {cell_m} m exceed "
            f"{MAX_CELLS}; use larger cells"
        )
    rows, cols = int(counts[1]), int(counts[0])
    grid = ClearanceGrid(lo, float(cell_m), np.full((rows, cols), np.inf))
    if samples.shape[0] == 0:
        return grid
    i, j, _ = grid.cells(samples)
    # Boxes and cylinders are solid: their outlines, drawn apart from the walls (a room's
    # outline encloses the room), are filled (holes under 4-connectivity: a diagonal step in
    # an outline does not let the outside in).
    solids = np.zeros((rows, cols), dtype=bool)
    solids[i[solid], j[solid]] = True
    occupied = ndimage.binary_fill_holes(solids)
    occupied[i, j] = True
    clearance = ndimage.distance_transform_edt(~occupied) * cell_m
    return ClearanceGrid(lo, float(cell_m), np.asarray(clearance, dtype=np.float64))


# --------------------------------------------------------------------------------------------
# Dijkstra and the path
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PathResult:
    """A path and its length.

    Attributes
    ----------
    length_m
        Metres along ``waypoints``; ``inf`` when there is no path (``waypoints`` then empty).
    waypoints
        (k, 2) float64, metres, world frame: the start, the corners, the goal.
    """

    length_m: float
    waypoints: FloatArray


_NO_PATH = PathResult(math.inf, np.empty((0, 2)))


@dataclass(frozen=True, eq=False)
class PathField:
    """Shortest grid distances from one start to every cell a disc of ``radius_m`` can reach.

    Attributes
    ----------
    grid
        The clearance grid searched.
    radius_m
        The disc's radius: cells with clearance >= it are free.
    start_xy
        (2,) metres, world frame.
    distance_m
        (rows, cols) float64, metres: the 16-neighbour grid distance from the start's cell
        (``inf``: not reached, or beyond the search's limit).
    free
        (rows, cols) bool: the cells the disc may stand on.
    predecessor
        (rows, cols) int64: the flat index of the previous cell on the way from the start
        (-1 at the start and where not reached).
    """

    grid: ClearanceGrid
    radius_m: float
    start_xy: FloatArray
    distance_m: FloatArray
    free: BoolArray
    predecessor: IntArray

    def reachable(self, xy: npt.ArrayLike) -> BoolArray:
        """(n,) whether the cells of points ``xy`` (n, 2) were reached."""
        i, j, inside = self.grid.cells(xy)
        return np.asarray(inside & np.isfinite(self.distance_m[i, j]), dtype=bool)

    def path_to(self, goal_xy: npt.ArrayLike) -> PathResult:
        """The path from the start to ``goal_xy``, pulled straight (module docstring).

        Returns
        -------
        PathResult
            Starting exactly at :attr:`start_xy` and ending exactly at ``goal_xy``; ``inf``
            and no waypoints if the goal's cell was not reached.
        """
        goal = np.asarray(goal_xy, dtype=np.float64)
        if goal.shape != (2,) or not np.all(np.isfinite(goal)):
            raise ValueError(f"goal_xy must be a finite (2,) point, got {goal_xy!r}")
        if not bool(self.reachable(goal[None])[0]):
            return _NO_PATH
        i, j, _ = self.grid.cells(goal[None])
        cols = self.grid.shape[1]
        chain = [int(i[0]) * cols + int(j[0])]
        # Following predecessors is sequential by nature: one step per cell of the path.
        while (prev := int(self.predecessor.flat[chain[-1]])) >= 0:
            chain.append(prev)
        flat = np.array(chain[::-1], dtype=np.int64)
        points = self.grid.centres(*np.divmod(flat, cols))
        points[0], points[-1] = self.start_xy, goal
        if points.shape[0] == 1:  # start and goal in one cell
            points = np.stack([self.start_xy, goal])
        corners = _pull_straight(points, self.free, self.grid)
        return PathResult(_polyline_length(corners), corners)


def _polyline_length(points: FloatArray) -> float:
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def _in_sight(
    a: FloatArray, targets: FloatArray, free: BoolArray, grid: ClearanceGrid
) -> BoolArray:
    """(t,) whether the segments from ``a`` (2,) to each of ``targets`` (t, 2) run over free
    cells only (sampled ``h/4`` apart, both ends included)."""
    n = np.ceil(np.hypot(*(targets - a).T) / (0.25 * grid.cell_m)).astype(np.int64) + 1
    which = np.repeat(np.arange(n.size), n)
    first = np.repeat(np.cumsum(n) - n, n)
    t = (np.arange(which.size) - first) / np.maximum(n[which] - 1, 1)
    samples = a + t[:, None] * (targets[which] - a)
    i, j, inside = grid.cells(samples)
    blocked = ~(inside & free[i, j])
    return np.asarray(np.bincount(which, weights=blocked, minlength=n.size) == 0, dtype=bool)


def _pull_straight(points: FloatArray, free: BoolArray, grid: ClearanceGrid) -> FloatArray:
    """The grid path ``points`` (k, 2) with every run of waypoints that the segment between
    its ends clears replaced by that segment; greedy from the start."""
    keep = [0]
    last = points.shape[0] - 1
    while keep[-1] < last:
        here = keep[-1]
        seen = np.flatnonzero(_in_sight(points[here], points[here + 1 :], free, grid))
        # The next grid waypoint is a grid step away and always allowed.
        keep.append(here + 1 + (int(seen[-1]) if seen.size else 0))
    return np.asarray(points[keep], dtype=np.float64)


def path_field(
    grid: ClearanceGrid, start_xy: npt.ArrayLike, radius_m: float, limit_m: float = math.inf
) -> PathField:
    """Dijkstra from ``start_xy`` over the cells a disc of ``radius_m`` may stand on.

    Parameters
    ----------
    grid
        From :func:`clearance_grid`.
    start_xy
        (2,) metres, world frame.
    radius_m
        The disc's radius, metres, >= 0.
    limit_m
        Stop the search at this grid distance, metres (``inf``: search everything).

    Returns
    -------
    PathField
        Nothing reached (every distance ``inf``) when the start's own cell is not free or
        lies outside the grid.
    """
    start = np.asarray(start_xy, dtype=np.float64)
    if start.shape != (2,) or not np.all(np.isfinite(start)):
        raise ValueError(f"start_xy must be a finite (2,) point, got {start_xy!r}")
    if not (math.isfinite(radius_m) and radius_m >= 0.0):
        raise ValueError(f"radius_m must be >= 0 and finite, got {radius_m!r}")
    if not limit_m > 0.0:
        raise ValueError(f"limit_m must be positive, got {limit_m!r}")
    rows, cols = grid.shape
    free = np.asarray(grid.clearance_m >= radius_m, dtype=bool)
    distance = np.full((rows, cols), np.inf)
    predecessor = np.full((rows, cols), -1, dtype=np.int64)
    si, sj, inside = grid.cells(start[None])
    if not (bool(inside[0]) and bool(free[si[0], sj[0]])):
        return PathField(grid, float(radius_m), start, distance, free, predecessor)
    node = np.full((rows + 4, cols + 4), -1, dtype=np.int64)
    free_flat = np.flatnonzero(free)
    node[2:-2, 2:-2].flat[free_flat] = np.arange(free_flat.size)
    padded = np.pad(free, 2)

    def shifted(array: npt.NDArray[np.generic], di: int, dj: int) -> npt.NDArray[np.generic]:
        return array[2 + di : 2 + di + rows, 2 + dj : 2 + dj + cols]

    src_rows, dst_rows, weights = [], [], []
    for (di, dj), between in _STEPS:
        ok = free & shifted(padded, di, dj)
        for bi, bj in between:
            ok &= shifted(padded, bi, bj)
        src_rows.append(node[2:-2, 2:-2][ok])
        dst_rows.append(shifted(node, di, dj)[ok])
        weights.append(np.full(int(ok.sum()), grid.cell_m * math.hypot(di, dj)))
    n = free_flat.size
    graph = csr_array(
        (np.concatenate(weights), (np.concatenate(src_rows), np.concatenate(dst_rows))),
        shape=(n, n),
    )
    start_node = int(node[2 + si[0], 2 + sj[0]])
    dist, pred = dijkstra(
        graph,
        directed=False,
        indices=np.array([start_node]),
        return_predecessors=True,
        limit=limit_m,
    )
    distance.flat[free_flat] = dist[0]
    predecessor.flat[free_flat] = np.where(pred[0] >= 0, free_flat[np.maximum(pred[0], 0)], -1)
    return PathField(grid, float(radius_m), start, distance, free, predecessor)


def shortest_path(
    world: World,
    start_xy: npt.ArrayLike,
    goal_xy: npt.ArrayLike,
    radius_m: float,
    cell_m: float = CELL_M,
) -> PathResult:
    """The shortest path of a disc of ``radius_m`` through ``world``'s static obstacles.

    Parameters
    ----------
    world
        Its static segments and circles (movers are ignored).
    start_xy, goal_xy
        (2,) metres, world frame.
    radius_m
        The disc's radius, metres (:func:`reference_radius_m`, :func:`turning_radius_m`).
    cell_m
        The grid's cell side, metres.

    Returns
    -------
    PathResult
        ``inf`` when there is none (start or goal where the disc does not fit, or no way
        between them). Discretisation error: module docstring.
    """
    ends = np.array([start_xy, goal_xy], dtype=np.float64)
    if ends.shape != (2, 2) or not np.all(np.isfinite(ends)):
        raise ValueError("shortest_path: start_xy and goal_xy must be finite (2,) points")
    grid = clearance_grid(world, cell_m, pad_m=radius_m + 2.0 * cell_m, include_xy=ends)
    return path_field(grid, ends[0], radius_m).path_to(ends[1])
