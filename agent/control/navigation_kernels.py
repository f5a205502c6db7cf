"""The compiled look-ups of the navigation field (:mod:`agent.control.navigation`).

The planner samples the field at a few dozen points per command (the arcs' ends and, four
cells about each, its slope); written in numpy each sample set cost about twenty
small-array operations (60-100 µs a call, 0.3 ms a command), and marking the obstacles'
cores in the map 0.2 ms a vector. Here one loop per call. Walking the field's path down its
cheapest neighbours (the planner's target and the intent's tail, twice a command) took
35 µs a call cell by cell in Python; :func:`path_points` takes 6.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.compiled import compiled, compiled_inline

IntArray = NDArray[np.int64]


@compiled_inline
def _bilinear(
    C: FloatArray, origin_x: float, origin_y: float, cell_m: float, x: float, y: float,
    top: float, goal_x: float, goal_y: float,
) -> float:  # fmt: skip
    n_y, n_x = C.shape
    fx = (x - origin_x) / cell_m - 0.5
    fy = (y - origin_y) / cell_m - 0.5
    if fx < -0.5 or fx > n_x - 0.5 or fy < -0.5 or fy > n_y - 0.5:
        return top + math.hypot(x - goal_x, y - goal_y)
    x0 = min(max(math.floor(fx), 0), n_x - 2)
    y0 = min(max(math.floor(fy), 0), n_y - 2)
    tx = min(max(fx - x0, 0.0), 1.0)
    ty = min(max(fy - y0, 0.0), 1.0)
    value: float = (
        C[y0, x0] * (1 - tx) * (1 - ty) + C[y0, x0 + 1] * tx * (1 - ty)
        + C[y0 + 1, x0] * (1 - tx) * ty + C[y0 + 1, x0 + 1] * tx * ty
    )  # fmt: skip
    return value


@compiled
def field_values(
    C: FloatArray, origin_x: float, origin_y: float, cell_m: float, xy: FloatArray,
    top: float, goal_x: float, goal_y: float,
) -> FloatArray:  # fmt: skip
    """The field ``C`` (ny, nx) at points ``xy`` (n, 2), bilinear between cell centres;
    outside the grid, ``top`` plus the distance to the goal."""
    out = np.empty(xy.shape[0])
    for i in range(xy.shape[0]):
        out[i] = _bilinear(C, origin_x, origin_y, cell_m, xy[i, 0], xy[i, 1], top, goal_x, goal_y)
    return out


@compiled
def field_descent(
    C: FloatArray, origin_x: float, origin_y: float, cell_m: float, xy: FloatArray,
    top: float, goal_x: float, goal_y: float,
) -> FloatArray:  # fmt: skip
    """The direction of steepest descent (rad) at points ``xy`` (n, 2): central differences
    of :func:`field_values` one cell apart."""
    out = np.empty(xy.shape[0])
    h = cell_m
    for i in range(xy.shape[0]):
        x, y = xy[i, 0], xy[i, 1]
        gx = _bilinear(C, origin_x, origin_y, cell_m, x + h, y, top, goal_x, goal_y) - _bilinear(
            C, origin_x, origin_y, cell_m, x - h, y, top, goal_x, goal_y
        )
        gy = _bilinear(C, origin_x, origin_y, cell_m, x, y + h, top, goal_x, goal_y) - _bilinear(
            C, origin_x, origin_y, cell_m, x, y - h, top, goal_x, goal_y
        )
        out[i] = math.atan2(-gy, -gx)
    return out


@compiled
def mark_cores(
    obstacle_s: FloatArray, stamp_s: float, origin_x: float, origin_y: float, cell_m: float,
    a: FloatArray, b: FloatArray, radius: FloatArray,
) -> None:  # fmt: skip
    """Stamp ``stamp_s`` into the cells of ``obstacle_s`` (ny, nx) holding the points of
    :func:`agent.control.navigation.core_points` (half a cell apart along each core
    ``a[k] → b[k]``, and round the rim of those with a radius)."""
    n_y, n_x = obstacle_s.shape
    spacing = 0.5 * cell_m
    for k in range(a.shape[0]):
        ax, ay, bx, by = a[k, 0], a[k, 1], b[k, 0], b[k, 1]
        count = math.ceil(math.hypot(bx - ax, by - ay) / spacing) + 1
        rim = math.ceil(2 * math.pi * radius[k] / spacing) if radius[k] > 0.0 else 0
        for i in range(count + rim):
            if i < count:
                f = i / max(count - 1, 1)
                px, py = ax + f * (bx - ax), ay + f * (by - ay)
            else:
                angle = 2 * math.pi * (i - count) / rim
                px = ax + radius[k] * math.cos(angle)
                py = ay + radius[k] * math.sin(angle)
            ix = math.floor((px - origin_x) / cell_m)
            iy = math.floor((py - origin_y) / cell_m)
            if 0 <= ix < n_x and 0 <= iy < n_y:
                obstacle_s[iy, ix] = stamp_s


@compiled
def path_points(
    next_cell: IntArray, n_y: int, n_x: int, origin_x: float, origin_y: float, cell_m: float,
    x: float, y: float, steps: int, every: int,
) -> FloatArray:  # fmt: skip
    """Waypoints (p, 2) down the field from the cell of ``(x, y)`` along ``next_cell`` (the
    flat index of each cell's cheapest neighbour, itself at the goal) for at most ``steps``
    cells: every ``every``-th cell's centre from the first, and the last; none if ``(x, y)``
    lies outside the grid. As :meth:`agent.control.navigation.NavigationField.path_reference`."""
    ix = math.floor((x - origin_x) / cell_m)
    iy = math.floor((y - origin_y) / cell_m)
    if not (0 <= ix < n_x and 0 <= iy < n_y):
        return np.zeros((0, 2))
    cells = np.empty(steps + 1, dtype=np.int64)
    cells[0] = iy * n_x + ix
    count = 1
    for _ in range(steps):
        j = next_cell[cells[count - 1]]
        if j == cells[count - 1]:
            break
        cells[count] = j
        count += 1
    picked = (count - 1) // every + 1
    extra = 1 if (count - 1) % every else 0
    out = np.empty((picked + extra, 2))
    for k in range(picked + extra):
        c = cells[k * every] if k < picked else cells[count - 1]
        out[k, 0] = origin_x + (c % n_x + 0.5) * cell_m
        out[k, 1] = origin_y + (c // n_x + 0.5) * cell_m
    return out


def warm_up() -> None:
    """Load (or compile, on the first use on a machine) every kernel of this module."""
    C = np.zeros((3, 3))
    xy = np.zeros((1, 2))
    field_values(C, 0.0, 0.0, 0.1, xy, 0.0, 0.0, 0.0)
    field_descent(C, 0.0, 0.0, 0.1, xy, 0.0, 0.0, 0.0)
    mark_cores(C, 0.0, 0.0, 0.0, 0.1, xy, xy, np.zeros(1))
    path_points(np.zeros(9, dtype=np.int64), 3, 3, 0.0, 0.0, 0.1, 0.0, 0.0, 2, 1)
