"""The vehicle's outline against the true world: clearance, and which obstacle is nearest.

Frames follow REP-103 (x forward, y left, angles counter-clockwise); metres, radians; poses
``(x_m, y_m, yaw_rad)`` of ``base_link`` in the world frame.

The outline is :class:`~agent.kinematics.vehicle.VehicleSpec`'s rectangle, ``length_m`` along
``base_link``'s x and ``width_m`` along its y, centred on its origin. Its *clearance* is the
exact Euclidean distance from the filled rectangle to the nearest of the world's static
segments (wall pieces and box faces) and circles (cylinders) and of the movers' circles:
0 when any of them touches or overlaps the outline, which is a collision.

Distances, per primitive, in the outline's own frame (half sides ``a``, ``b``):

* a point ``(u, v)``: ``hypot(max(|u| - a, 0), max(|v| - b, 0))``, 0 inside;
* a circle: its centre's distance less its radius, at least 0;
* a segment: 0 if it meets the rectangle (no separating axis among the rectangle's two axes
  and the segment's normal: the separating axis theorem for two convex sets), else the
  smallest of its two ends' distances to the rectangle and the rectangle's four corners'
  distances to the segment (two disjoint convex polygons are nearest at a vertex of one).

Each pose is tested in one compiled pass over the primitives
(:mod:`agent.sim.footprint_kernels`), exactly only against those whose distance from the
outline's centre, less its circumradius, is within the nearest exact distance found; no
spatial index, since the worlds driven in hold tens to hundreds of primitives (a culled world
from :meth:`~agent.sim.world.World.nearby` can be passed instead of a large one).
:func:`outline_clearances_reference` is the same in numpy (every pose against every
primitive, chunked over poses), which the kernel equals to the bit.

Obstacle ids follow the world: :attr:`~agent.sim.world.World.segments_obstacle` and
:attr:`~agent.sim.world.World.circles_obstacle` for static primitives, and
:attr:`~agent.sim.world.World.mover_id_base` ``+ j`` for mover ``j``; -1 when there is
nothing at all (the clearance is then ``inf``).
"""

from __future__ import annotations

import functools

import numpy as np
import numpy.typing as npt

from agent.arrays import FloatArray
from agent.kinematics.vehicle import VehicleSpec
from agent.sim.footprint_kernels import nearest_primitives
from agent.sim.world import World

__all__ = [
    "IntArray",
    "outline_clearance",
    "outline_clearances",
    "outline_clearances_reference",
    "outline_corners",
]

IntArray = npt.NDArray[np.int64]

_CELLS_PER_CHUNK = 1 << 16
"""Pose-primitive pairs handled at once (a few (chunk, m, 4) float64 arrays: about 2 MB each)."""


def outline_corners(poses: npt.ArrayLike, vehicle: VehicleSpec | None = None) -> FloatArray:
    """The outline's four corners at each pose, counter-clockwise from front right.

    Parameters
    ----------
    poses
        (3,) or (n, 3) ``(x_m, y_m, yaw_rad)`` in the world frame.
    vehicle
        The outline's size (default :class:`VehicleSpec` ``()``).

    Returns
    -------
    FloatArray
        (4, 2) or (n, 4, 2), metres, world frame: front right, front left, rear left, rear
        right.
    """
    spec = vehicle if vehicle is not None else VehicleSpec()
    p = _poses(poses)
    a, b = 0.5 * spec.length_m, 0.5 * spec.width_m
    local = np.array([[a, -b], [a, b], [-a, b], [-a, -b]])
    c, s = np.cos(p[:, 2:3]), np.sin(p[:, 2:3])  # (n, 1)
    x = p[:, 0:1] + c * local[:, 0] - s * local[:, 1]
    y = p[:, 1:2] + s * local[:, 0] + c * local[:, 1]
    out = np.stack([x, y], axis=-1)
    return out[0] if np.ndim(poses) == 1 else out


def outline_clearance(
    world: World,
    pose: npt.ArrayLike,
    mover_xy: npt.ArrayLike | None = None,
    mover_radius_m: npt.ArrayLike | None = None,
    vehicle: VehicleSpec | None = None,
) -> tuple[float, int]:
    """Clearance between the outline at one pose and the true world.

    Parameters
    ----------
    world
        Its static segments and circles (the movers' places come from ``mover_xy``).
    pose
        (3,) ``(x_m, y_m, yaw_rad)`` of ``base_link`` in the world frame.
    mover_xy
        (m, 2) movers' centres, metres, world frame (``None``: no movers), in the world's
        mover order.
    mover_radius_m
        (m,) their radii, metres, > 0.
    vehicle
        The outline's size (default :class:`VehicleSpec` ``()``).

    Returns
    -------
    (clearance_m, obstacle)
        The smallest distance in metres (0: touching or overlapping; ``inf`` with nothing in
        the world) and the id of the obstacle at that distance (-1 with nothing).

    Raises
    ------
    ValueError
        For a pose or movers of the wrong shape or not finite.
    """
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (3,):
        raise ValueError(f"pose must be (x_m, y_m, yaw_rad), got shape {p.shape}")
    d, ids = outline_clearances(world, p[None, :], mover_xy, mover_radius_m, vehicle)
    return float(d[0]), int(ids[0])


def outline_clearances(
    world: World,
    poses: npt.ArrayLike,
    mover_xy: npt.ArrayLike | None = None,
    mover_radius_m: npt.ArrayLike | None = None,
    vehicle: VehicleSpec | None = None,
) -> tuple[FloatArray, IntArray]:
    """Clearance between the outline and the true world at many poses (a path, say).

    Parameters
    ----------
    world
        Its static segments and circles.
    poses
        (n, 3) ``(x_m, y_m, yaw_rad)`` of ``base_link`` in the world frame.
    mover_xy
        Movers' centres, metres, world frame: (m, 2) the same for every pose, or (n, m, 2)
        per pose (where they were when the vehicle was at each pose). ``None``: no movers.
    mover_radius_m
        (m,) their radii, metres, > 0.
    vehicle
        The outline's size (default :class:`VehicleSpec` ``()``).

    Returns
    -------
    clearance_m
        (n,) float64, metres: the smallest distance at each pose (0: a collision; ``inf``
        with nothing in the world).
    obstacle
        (n,) int64: the id of the obstacle at that distance (-1 with nothing); at 0, the
        first one overlapping, walls and boxes before cylinders before movers.

    Computed by :func:`agent.sim.footprint_kernels.nearest_primitives` (compiled, with a broad
    phase), equal to :func:`outline_clearances_reference` to the bit.

    Raises
    ------
    ValueError
        For poses or movers of the wrong shape or not finite.
    """
    spec = vehicle if vehicle is not None else VehicleSpec()
    p = _poses(poses)
    centers, radii = _movers(mover_xy, mover_radius_m, p.shape[0])
    segments, circles, ids = _tables(world)
    return nearest_primitives(
        p, segments, circles, np.ascontiguousarray(centers), radii,
        0.5 * spec.length_m, 0.5 * spec.width_m, ids, world.mover_id_base,
    )  # fmt: skip


def outline_clearances_reference(
    world: World,
    poses: npt.ArrayLike,
    mover_xy: npt.ArrayLike | None = None,
    mover_radius_m: npt.ArrayLike | None = None,
    vehicle: VehicleSpec | None = None,
) -> tuple[FloatArray, IntArray]:
    """:func:`outline_clearances` in numpy: every pose against every primitive, in chunks."""
    spec = vehicle if vehicle is not None else VehicleSpec()
    p = _poses(poses)
    n = p.shape[0]
    centers, radii = _movers(mover_xy, mover_radius_m, n)
    m, k, j = world.segments_start.shape[0], world.circles_radius.size, radii.size
    ids = np.concatenate(
        [
            world.segments_obstacle,
            world.circles_obstacle,
            np.arange(world.mover_id_base, world.mover_id_base + j, dtype=np.int64),
        ]
    )
    clearance = np.full(n, np.inf)
    obstacle = np.full(n, -1, dtype=np.int64)
    if ids.size == 0 or n == 0:
        return clearance, obstacle
    half = (0.5 * spec.length_m, 0.5 * spec.width_m)
    # Every point in one array, so that one rotation takes them all into the outline's frame:
    # segment starts (m), segment ends (m), circle centres (k), then the movers' (j).
    static = np.concatenate([world.segments_start, world.segments_end, world.circles_center])
    circle_radius = np.concatenate([world.circles_radius, radii])
    rows = max(1, _CELLS_PER_CHUNK // (2 * m + k + j))
    for lo in range(0, n, rows):
        chunk = p[lo : lo + rows]
        if j:
            moving = centers if centers.shape[0] == 1 else centers[lo : lo + rows]
            r = chunk.shape[0]
            points = np.concatenate(
                [
                    np.broadcast_to(static, (r, *static.shape)),
                    np.broadcast_to(moving, (r, *moving.shape[1:])),
                ],
                axis=1,
            )
        else:
            points = static[None, :, :]
        u, v = _to_local(points, chunk)  # (rows, 2m + k + j) each
        d = np.empty((chunk.shape[0], m + k + j))
        if m:
            d[:, :m] = _segment_distance(u[:, :m], v[:, :m], u[:, m : 2 * m], v[:, m : 2 * m], half)
        if k + j:
            to_center = _point_distance(u[:, 2 * m :], v[:, 2 * m :], half)
            d[:, m:] = np.maximum(to_center - circle_radius, 0.0)
        best = np.argmin(d, axis=1)
        clearance[lo : lo + rows] = d[np.arange(d.shape[0]), best]
        obstacle[lo : lo + rows] = ids[best]
    return clearance, obstacle


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=16)
def _tables(world: World) -> tuple[FloatArray, FloatArray, IntArray]:
    """The world's static primitives as the kernel reads them: (m, 4) segments ``(x0, y0,
    x1, y1)``, (k, 3) circles ``(x, y, radius)``, and their (m + k,) obstacle ids. A world is
    immutable and hashed by identity, so they are made once per world."""
    segments = np.ascontiguousarray(np.concatenate([world.segments_start, world.segments_end], 1))
    circles = np.ascontiguousarray(
        np.concatenate([world.circles_center, world.circles_radius[:, None]], 1)
    )
    return segments, circles, np.concatenate([world.segments_obstacle, world.circles_obstacle])


def _poses(poses: npt.ArrayLike) -> FloatArray:
    """``poses`` as (n, 3) finite float64."""
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim == 1:
        p = p[None, :]
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"poses must be (n, 3) (x_m, y_m, yaw_rad), got shape {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError("poses must be finite")
    return p


def _movers(
    mover_xy: npt.ArrayLike | None, mover_radius_m: npt.ArrayLike | None, n: int
) -> tuple[FloatArray, FloatArray]:
    """Movers as (1 or n, m, 2) centres and (m,) radii."""
    if mover_xy is None and mover_radius_m is None:
        return np.zeros((1, 0, 2)), np.zeros(0)
    if mover_xy is None or mover_radius_m is None:
        raise ValueError("mover_xy and mover_radius_m must be given together")
    radii = np.asarray(mover_radius_m, dtype=np.float64)
    if radii.ndim != 1:
        raise ValueError(f"mover_radius_m must be (m,), got shape {radii.shape}")
    xy = np.asarray(mover_xy, dtype=np.float64)
    if xy.size == 0 and radii.size == 0:
        return np.zeros((1, 0, 2)), radii
    if xy.ndim == 2:
        xy = xy[None, :, :]
    if xy.ndim != 3 or xy.shape[1:] != (radii.size, 2) or xy.shape[0] not in (1, n):
        raise ValueError(
            f"mover_xy must be (m, 2) or (n, m, 2) with m = {radii.size} and n = {n}, "
            f"got shape {xy.shape}"
        )
    if not (np.isfinite(xy).all() and np.isfinite(radii).all() and (radii > 0.0).all()):
        raise ValueError("mover_xy must be finite and mover_radius_m finite and > 0")
    return xy, radii


def _to_local(points: FloatArray, poses: FloatArray) -> tuple[FloatArray, FloatArray]:
    """World points (1 or n, P, 2) into each pose's frame: coordinates u, v, each (n, P)."""
    c, s = np.cos(poses[:, 2:3]), np.sin(poses[:, 2:3])
    dx = points[..., 0] - poses[:, 0:1]
    dy = points[..., 1] - poses[:, 1:2]
    return c * dx + s * dy, c * dy - s * dx


def _point_distance(u: FloatArray, v: FloatArray, half: tuple[float, float]) -> FloatArray:
    """Distance from local points ``(u, v)`` to the filled rectangle ``|u| <= a, |v| <= b``."""
    du = np.maximum(np.abs(u) - half[0], 0.0)
    dv = np.maximum(np.abs(v) - half[1], 0.0)
    return np.hypot(du, dv)


def _segment_distance(
    x0: FloatArray, y0: FloatArray, x1: FloatArray, y1: FloatArray, half: tuple[float, float]
) -> FloatArray:
    """Distance from local segments, ends ``(x0, y0)`` and ``(x1, y1)``, to the filled
    rectangle ``|u| <= a, |v| <= b``."""
    a, b = half
    dx, dy = x1 - x0, y1 - y0
    # Separating axes: the rectangle's u and v, and the segment's normal (-dy, dx), on which
    # the rectangle spans ±(a |dy| + b |dx|) and the segment is the one value x1·y0 - x0·y1.
    apart = (
        (np.minimum(x0, x1) > a)
        | (np.maximum(x0, x1) < -a)
        | (np.minimum(y0, y1) > b)
        | (np.maximum(y0, y1) < -b)
        | (np.abs(x1 * y0 - x0 * y1) > a * np.abs(dy) + b * np.abs(dx))
    )
    ends = np.minimum(_point_distance(x0, y0, half), _point_distance(x1, y1, half))
    length2 = dx * dx + dy * dy
    inverse = 1.0 / np.where(length2 > 0.0, length2, 1.0)
    ex = _CORNERS_U[:, None, None] * a - x0  # (4, n, m): from each segment's start to corners
    ey = _CORNERS_V[:, None, None] * b - y0
    t = np.clip((ex * dx + ey * dy) * inverse, 0.0, 1.0)
    to_corners = np.hypot(ex - t * dx, ey - t * dy).min(axis=0)
    return np.where(apart, np.minimum(ends, to_corners), 0.0)


_CORNERS_U = np.array([1.0, 1.0, -1.0, -1.0])
_CORNERS_V = np.array([-1.0, 1.0, 1.0, -1.0])
