"""Poses and frames for scoring: where truth lies in the drifting ``odom`` frame.

Frames follow REP-103 (x forward, y left, angles counter-clockwise); metres and radians.
A pose ``(x, y, yaw)`` places ``base_link`` in a parent frame: ``world`` for the simulation's
truth, ``odom`` for the wheel odometry.

**Truth in ``odom``.** The odometry believes the vehicle is at ``T_odom(t)`` while it truly is
at ``T_true(t)``; a perfect tracker fed this odometry sees a world point ``p`` (world frame)
at ``T_odom(t)·T_true(t)⁻¹·p`` in ``odom``: that is where it should put it, and where scoring
compares its tracks with the truth (:func:`world_to_odom`). The map changes as the odometry
drifts, so it is taken at each scan's own stamp.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from agent.arrays import FloatArray, wrap_angle

__all__ = [
    "PoseHistory",
    "line_params",
    "rotation",
    "to_frame",
    "world_to_odom",
    "wrap_angle",
]


def rotation(yaw_rad: float) -> FloatArray:
    """The 2×2 rotation by ``yaw_rad`` (counter-clockwise)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([[c, -s], [s, c]])


def to_frame(pose: npt.ArrayLike, points: npt.ArrayLike) -> FloatArray:
    """Points given in the frame of ``pose`` mapped into that pose's parent frame.

    Parameters
    ----------
    pose
        (x, y, yaw) of the child frame in the parent, metres and radians.
    points
        (..., 2) points in the child frame, metres.

    Returns
    -------
    numpy.ndarray
        (..., 2) the same points in the parent frame.
    """
    x, y, yaw = (float(v) for v in np.asarray(pose, dtype=np.float64))
    p = np.asarray(points, dtype=np.float64)
    return np.asarray(p @ rotation(yaw).T + np.array([x, y]), dtype=np.float64)


def world_to_odom(
    true_pose: npt.ArrayLike, odom_pose: npt.ArrayLike, points_world: npt.ArrayLike
) -> FloatArray:
    """World points where a tracker using this odometry should see them, ``odom`` frame.

    ``T_odom·T_true⁻¹·p``, with both poses at the same stamp.

    Parameters
    ----------
    true_pose
        (x, y, yaw) of ``base_link`` in ``world`` (the truth).
    odom_pose
        (x, y, yaw) of ``base_link`` in ``odom`` (the odometry) at the same stamp.
    points_world
        (..., 2) points in the world frame, metres.

    Returns
    -------
    numpy.ndarray
        (..., 2) the points in ``odom``, metres.
    """
    tx, ty, tyaw = (float(v) for v in np.asarray(true_pose, dtype=np.float64))
    p = np.asarray(points_world, dtype=np.float64)
    in_base = (p - np.array([tx, ty])) @ rotation(tyaw)  # R(yaw)ᵀ·(p - t), row vectors
    return to_frame(odom_pose, in_base)


def line_params(start: FloatArray, end: FloatArray) -> FloatArray:
    """(α, ρ) of the lines through ``start`` and ``end`` ((n, 2) each), as in ``features/1``:
    ``x·cos α + y·sin α = ρ`` with ρ >= 0 (the normal points away from the origin), (n, 2)."""
    d = np.asarray(end, dtype=np.float64) - np.asarray(start, dtype=np.float64)
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    rho = np.einsum("ij,ij->i", normal, start)
    normal = np.where((rho < 0.0)[:, None], -normal, normal)
    return np.stack([np.arctan2(normal[:, 1], normal[:, 0]), np.abs(rho)], axis=1)


class PoseHistory:
    """Poses by time, interpolated linearly (the yaw unwrapped): a record of ``world_truth``
    or ``odometry`` messages, for the pose at a scan's stamp.

    At 20-50 Hz and the vehicle's 0.4 m/s and 1 rad/s at most, a straight line between two
    samples departs from the true arc by under 1 mm and 1 mrad.
    """

    def __init__(self) -> None:
        self._t: list[float] = []
        self._pose: list[tuple[float, float, float]] = []

    def __len__(self) -> int:
        return len(self._t)

    @property
    def last_s(self) -> float:
        """The latest time recorded (-inf before any)."""
        return self._t[-1] if self._t else -math.inf

    def add(self, t_s: float, x: float, y: float, yaw: float) -> None:
        """Append a pose; one not later than the last is ignored (a repeat)."""
        if self._t and t_s <= self._t[-1]:
            return
        if self._pose:
            yaw = self._pose[-1][2] + float(wrap_angle(yaw - self._pose[-1][2]))
        self._t.append(t_s)
        self._pose.append((x, y, yaw))

    def at(self, t_s: float) -> FloatArray | None:
        """(x, y, yaw) at ``t_s``; ``None`` outside the recorded span (no extrapolation)."""
        if not self._t or t_s < self._t[0] or t_s > self._t[-1]:
            return None
        t = np.asarray(self._t)
        poses = np.asarray(self._pose)
        return np.array([float(np.interp(t_s, t, poses[:, i])) for i in range(3)])
