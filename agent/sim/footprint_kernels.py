"""The outline's compiled clearance (:func:`agent.sim.footprint.outline_clearances`; why
compiled: :mod:`agent.compiled`).

The world simulator tests the outline a handful of times a tick (every 2 cm of motion)
against tens of primitives; in numpy each test cost a dozen whole-array calls over (poses,
primitives) arrays of a few hundred cells, about 0.3 ms a tick whatever the sizes. Here one
pass per pose, with a broad phase: a primitive is tested exactly only if its distance from
the outline's centre, less the outline's circumradius, is within the nearest exact distance
found (every point of the outline is within the circumradius of its centre, so no primitive
skipped can be as near as the nearest). The exact distances are those of
:mod:`agent.sim.footprint` (its module docstring), computed in the same order of operations
as its numpy formulation, :func:`agent.sim.footprint.outline_clearances_reference`, which the
tests compare this with.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from agent.arrays import FloatArray
from agent.compiled import compiled, compiled_inline

IntArray = npt.NDArray[np.int64]

BROAD_PHASE_MARGIN_M = 1e-9
"""Slack on the broad phase's lower bound, far above its rounding (coordinates of ~1e3 m
round at ~1e-13 m) and far below anything measured."""


@compiled
def nearest_primitives(
    poses: FloatArray,
    segments: FloatArray,
    circles: FloatArray,
    mover_xy: FloatArray,
    mover_radius: FloatArray,
    half_length_m: float,
    half_width_m: float,
    static_ids: IntArray,
    mover_id_base: int,
) -> tuple[FloatArray, IntArray]:
    """Clearance of the outline at each pose and the obstacle at that distance.

    Parameters
    ----------
    poses
        (n, 3) ``(x_m, y_m, yaw_rad)``, world frame.
    segments
        (m, 4) static segments ``(x0, y0, x1, y1)``, metres, world frame.
    circles
        (k, 3) static circles ``(x, y, radius)``, metres.
    mover_xy
        (1 or n, j, 2) movers' centres, the same for every pose or one row per pose.
    mover_radius
        (j,) their radii, metres.
    half_length_m, half_width_m
        The outline's half sides along ``base_link``'s x and y.
    static_ids
        (m + k,) the segments' then the circles' obstacle ids.
    mover_id_base
        Mover ``q``'s id is ``mover_id_base + q``.

    Returns
    -------
    clearance, obstacle
        (n,) metres (``inf`` with no primitive); (n,) the nearest primitive's obstacle id,
        the first of equals among segments, then circles, then movers; -1 with none.
    """
    n, m, k, j = poses.shape[0], segments.shape[0], circles.shape[0], mover_radius.size
    a, b = half_length_m, half_width_m
    reach = math.hypot(a, b)
    columns = m + k + j
    clearance = np.full(n, np.inf)
    obstacle = np.full(n, -1, dtype=np.int64)
    bound = np.empty(columns)
    for i in range(n):
        x, y, yaw = poses[i, 0], poses[i, 1], poses[i, 2]
        c, s = math.cos(yaw), math.sin(yaw)
        row = 0 if mover_xy.shape[0] == 1 else i
        # Broad phase: a lower bound on every primitive's distance; then the nearest by
        # that bound tested exactly, so that the pass below can skip the rest.
        first = -1
        for col in range(columns):
            bound[col] = _lower_bound(x, y, col, segments, circles, mover_xy, row, mover_radius)
            bound[col] -= reach + BROAD_PHASE_MARGIN_M
            if first < 0 or bound[col] < bound[first]:
                first = col
        if first < 0:
            continue
        best = _exact(x, y, c, s, first, segments, circles, mover_xy, row, mover_radius, a, b)
        nearest, at = np.inf, -1
        for col in range(columns):
            if bound[col] > best:
                continue
            d = _exact(x, y, c, s, col, segments, circles, mover_xy, row, mover_radius, a, b)
            if d < nearest:
                nearest, at = d, col
            best = min(best, d)
        clearance[i] = nearest
        obstacle[i] = static_ids[at] if at < m + k else mover_id_base + at - m - k
    return clearance, obstacle


@compiled_inline
def _lower_bound(
    x: float,
    y: float,
    col: int,
    segments: FloatArray,
    circles: FloatArray,
    mover_xy: FloatArray,
    row: int,
    mover_radius: FloatArray,
) -> float:
    """Distance from the point ``(x, y)`` to primitive ``col`` (a segment, circle or mover)."""
    m, k = segments.shape[0], circles.shape[0]
    if col < m:
        x0, y0 = segments[col, 0], segments[col, 1]
        ex, ey = segments[col, 2] - x0, segments[col, 3] - y0
        px, py = x - x0, y - y0
        den = ex * ex + ey * ey
        t = 0.0
        if den > 0.0:
            t = min(max((px * ex + py * ey) / den, 0.0), 1.0)
        return math.hypot(px - t * ex, py - t * ey)
    if col < m + k:
        q = col - m
        return float(math.hypot(circles[q, 0] - x, circles[q, 1] - y) - circles[q, 2])
    q = col - m - k
    return float(math.hypot(mover_xy[row, q, 0] - x, mover_xy[row, q, 1] - y) - mover_radius[q])


@compiled_inline
def _exact(
    x: float,
    y: float,
    c: float,
    s: float,
    col: int,
    segments: FloatArray,
    circles: FloatArray,
    mover_xy: FloatArray,
    row: int,
    mover_radius: FloatArray,
    a: float,
    b: float,
) -> float:
    """Exact distance from the outline at ``(x, y)``, heading cosine ``c`` and sine ``s``, to
    primitive ``col``: points taken into the outline's frame as
    :func:`agent.sim.footprint._to_local` does."""
    m, k = segments.shape[0], circles.shape[0]
    if col < m:
        dx, dy = segments[col, 0] - x, segments[col, 1] - y
        x0, y0 = c * dx + s * dy, c * dy - s * dx
        dx, dy = segments[col, 2] - x, segments[col, 3] - y
        x1, y1 = c * dx + s * dy, c * dy - s * dx
        return _segment_distance(x0, y0, x1, y1, a, b)
    if col < m + k:
        q = col - m
        px, py, radius = circles[q, 0], circles[q, 1], circles[q, 2]
    else:
        q = col - m - k
        px, py, radius = mover_xy[row, q, 0], mover_xy[row, q, 1], mover_radius[q]
    dx, dy = px - x, py - y
    u, v = c * dx + s * dy, c * dy - s * dx
    return float(max(_point_distance(u, v, a, b) - radius, 0.0))


@compiled_inline
def _point_distance(u: float, v: float, a: float, b: float) -> float:
    """Distance from the local point ``(u, v)`` to the filled rectangle ``|u| <= a, |v| <= b``."""
    return math.hypot(max(abs(u) - a, 0.0), max(abs(v) - b, 0.0))


@compiled_inline
def _segment_distance(x0: float, y0: float, x1: float, y1: float, a: float, b: float) -> float:
    """Distance from the local segment ``(x0, y0) → (x1, y1)`` to the filled rectangle:
    0 if no separating axis, else the least of its ends' distances to the rectangle and the
    rectangle's corners' distances to it."""
    dx, dy = x1 - x0, y1 - y0
    apart = (
        min(x0, x1) > a
        or max(x0, x1) < -a
        or min(y0, y1) > b
        or max(y0, y1) < -b
        or abs(x1 * y0 - x0 * y1) > a * abs(dy) + b * abs(dx)
    )
    if not apart:
        return 0.0
    ends = min(_point_distance(x0, y0, a, b), _point_distance(x1, y1, a, b))
    length2 = dx * dx + dy * dy
    inverse = 1.0 / (length2 if length2 > 0.0 else 1.0)
    to_corners = np.inf
    for corner in range(4):
        ex = (a if corner < 2 else -a) - x0  # front right, front left, rear left, rear right
        ey = (-b if corner == 0 or corner == 3 else b) - y0
        t = min(max((ex * dx + ey * dy) * inverse, 0.0), 1.0)
        to_corners = min(to_corners, math.hypot(ex - t * dx, ey - t * dy))
    return min(ends, to_corners)
