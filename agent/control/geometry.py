"""Plane geometry of the controller: the outline, motions on arcs, distances to capsules.

A *motion* is a unit twist ``(v̂, ŵ)`` scaled so that no point of the outline moves faster than
1 m per unit of its parameter ``d``: ``|v̂| + r·|ŵ| = 1`` with ``r`` the outline's
circumradius. Driving ``(v, w)`` for ``t`` seconds is the motion ``(v, w)/u`` at
``d = u·t``, ``u = |v| + r·|w|``; ``d`` is the furthest any point of the vehicle has moved.
Exact unicycle poses along it (REP-103, base_link at the start):

    θ(d) = ŵ d,   x(d) = v̂ sin(ŵ d)/ŵ,   y(d) = v̂ (1 − cos(ŵ d))/ŵ   (x = v̂ d, y = 0 if ŵ = 0)

Obstacles are *capsules*: the points within a radius of a segment ``a → b`` (a point when
``a = b``).
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import BoolArray, FloatArray, wrap_angle
from agent.kinematics.vehicle import VehicleSpec

__all__ = [
    "motion_poses",
    "outline_perimeter",
    "point_segment_distance",
    "rectangle_segment_distance",
    "sweep_points",
    "unit_motion",
    "wrap_angle",
]


def outline_perimeter(spec: VehicleSpec, spacing_m: float) -> FloatArray:
    """Points on the outline's perimeter, ``base_link``, (p, 2) m: the corners and points
    at most ``spacing_m`` apart along each side."""
    hx, hy = 0.5 * spec.length_m, 0.5 * spec.width_m
    corners = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    points = []
    for i in range(4):
        a, b = corners[i], corners[(i + 1) % 4]
        n = max(1, math.ceil(float(np.hypot(*(b - a))) / spacing_m))
        f = np.arange(n)[:, None] / n
        points.append(a + f * (b - a))
    return np.concatenate(points)


def unit_motion(v: FloatArray, w: FloatArray, radius_m: float) -> tuple[FloatArray, FloatArray]:
    """The unit motions ``(v̂, ŵ)`` of twists ``(v, w)`` (m/s, rad/s), same shapes; a zero
    twist gives the zero motion."""
    u = np.abs(v) + radius_m * np.abs(w)
    scale = np.divide(1.0, u, out=np.zeros_like(u), where=u > 0.0)
    return v * scale, w * scale


def motion_poses(v_unit: FloatArray, w_unit: FloatArray, d: FloatArray) -> FloatArray:
    """Poses ``(…, n, 3)`` (x, y, θ in the start's ``base_link``) of motions ``(…,)`` at
    displacements ``d`` (n,), by the exact unicycle equations of the module docstring."""
    v = np.asarray(v_unit, dtype=np.float64)[..., None]
    w = np.asarray(w_unit, dtype=np.float64)[..., None]
    theta = w * d
    small = np.abs(w) < 1e-9
    w_safe = np.where(small, 1.0, w)
    x = np.where(small, v * d, v * np.sin(theta) / w_safe)
    y = np.where(small, 0.5 * v * w * d * d, v * (1.0 - np.cos(theta)) / w_safe)
    return np.stack(np.broadcast_arrays(x, y, theta), axis=-1)


def arc_end_points(
    v_unit: FloatArray, w_unit: FloatArray, d: FloatArray, pose: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(x, y, θ)``, each (n,): where the unit motions ``(v_unit, w_unit)`` (n,) end after
    displacements ``d`` (n,) from ``pose`` (3,), in ``pose``'s frame (``odom``), ``θ`` the
    turn (the exact unicycle arcs, straight where ``|w_unit|`` < 1e-9)."""
    th = w_unit * d
    small = np.abs(w_unit) < 1e-9
    w_safe = np.where(small, 1.0, w_unit)
    ex = np.where(small, v_unit * d, v_unit * np.sin(th) / w_safe)
    ey = np.where(small, 0.0, v_unit * (1.0 - np.cos(th)) / w_safe)
    x, y = from_pose(pose, ex, ey)
    return x, y, th


def from_pose(pose: FloatArray, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Points ``(x, y)`` given in the frame of ``pose`` (3,), in ``pose``'s own frame."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return pose[0] + c * x - s * y, pose[1] + s * x + c * y


def roll_out(
    pose: FloatArray, v_unit: float, w_unit: float, d_end: float, count: int
) -> FloatArray:
    """(count, 2): a plan's roll-out, the points of the unit motion from ``pose`` at
    ``count`` displacements evenly spaced over ``(0, d_end]``."""
    d = np.linspace(0.0, d_end, count + 1)[1:]
    poses = motion_poses(np.array(v_unit), np.array(w_unit), d)
    return np.stack(from_pose(pose, poses[:, 0], poses[:, 1]), axis=1)


def sweep_points(poses: FloatArray, outline: FloatArray) -> FloatArray:
    """The outline's points ``(…, n, p, 2)`` at poses ``(…, n, 3)``, in the poses' frame."""
    c, s = np.cos(poses[..., 2])[..., None], np.sin(poses[..., 2])[..., None]
    px, py = outline[:, 0], outline[:, 1]
    x = poses[..., 0, None] + c * px - s * py
    y = poses[..., 1, None] + s * px + c * py
    return np.stack([x, y], axis=-1)


def point_segment_distance(p: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Distance (m) from points ``p`` (…, 2) to segments ``a → b`` (…, 2), broadcast."""
    ab = b - a
    ap = p - a
    den = np.sum(ab * ab, axis=-1)
    num = np.sum(ap * ab, axis=-1)
    shape = np.broadcast_shapes(num.shape, den.shape)
    t = np.clip(np.divide(num, den, out=np.zeros(shape), where=den > 0.0), 0.0, 1.0)
    dx = ap[..., 0] - t * ab[..., 0]
    dy = ap[..., 1] - t * ab[..., 1]
    return np.asarray(np.hypot(dx, dy), dtype=np.float64)


def _point_rectangle_distance(p: FloatArray, hx: float, hy: float) -> FloatArray:
    dx = np.maximum(np.abs(p[..., 0]) - hx, 0.0)
    dy = np.maximum(np.abs(p[..., 1]) - hy, 0.0)
    return np.asarray(np.hypot(dx, dy), dtype=np.float64)


def _cross(o: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    return np.asarray(
        (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1])
        - (a[..., 1] - o[..., 1]) * (b[..., 0] - o[..., 0]),
        dtype=np.float64,
    )


def _segments_cross(a: FloatArray, b: FloatArray, c: FloatArray, d: FloatArray) -> BoolArray:
    """Whether segments a-b and c-d properly cross (…), broadcast."""
    d1, d2 = _cross(c, d, a), _cross(c, d, b)
    d3, d4 = _cross(a, b, c), _cross(a, b, d)
    return np.asarray((d1 * d2 < 0.0) & (d3 * d4 < 0.0))


def rectangle_segment_distance(a: FloatArray, b: FloatArray, hx: float, hy: float) -> FloatArray:
    """Distance (m) between the rectangle ``|x| <= hx, |y| <= hy`` and segments ``a → b``
    (…, 2) in its frame; 0 where they meet.

    The smaller of the end points' distances to the rectangle and the corners' distances to
    the segment, unless the segment crosses a diagonal (then it cuts through)."""
    corners = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    d = np.minimum(_point_rectangle_distance(a, hx, hy), _point_rectangle_distance(b, hx, hy))
    for corner in corners:
        d = np.minimum(d, point_segment_distance(corner, a, b))
    cut = np.logical_or(
        _segments_cross(a, b, corners[0], corners[2]), _segments_cross(a, b, corners[1], corners[3])
    )
    return np.asarray(np.where(cut, 0.0, d), dtype=np.float64)
