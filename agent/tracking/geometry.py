"""Features from ``base_link`` into ``odom``, and the drift of ``odom`` as process noise.

Poses are ``(x, y, yaw)`` of ``base_link`` in ``odom`` (m, m, rad; REP-103). A point ``p``
in ``base_link`` lies at ``t + R(yaw)·p`` in ``odom``; a line ``x·cos α + y·sin α = ρ`` at
``α' = α + yaw``, ``ρ' = ρ + t·(cos α', sin α')``.

**Why the pose covariance is not added to each measurement.** The odometry pose's error is
shared by every scan since the start: adding it to each feature would treat one error as many
independent ones. It is instead modelled where it acts, as the motion of ``odom`` against the
world: while the odometry's error grows, a static feature's coordinates in ``odom`` move. To
first order a feature at ``p`` in ``odom`` moves by ``J·δ`` when the vehicle's pose error
changes by ``δ`` (``J``: :func:`point_drift_jacobian`, the lever arm from the vehicle to the
feature), so the process noise is ``Q = J·ΔΣ·Jᵀ``.

**ΔΣ is the new error, not the growth of Σ.** Between two poses the odometry covariance grows
as ``Σ₂ = F·Σ₁·Fᵀ + Σ_new`` (``F``: :func:`pose_motion_jacobian`): the earlier heading error
carried along the path (``F``), plus the error the wheels added on the way (``Σ_new``). Only
the second moves ``odom`` against the world: an old heading error rotates the whole path, the
vehicle and the features seen from it alike, and a feature's ``odom`` coordinates stay where
they were (``J(v₂)·F = J(v₁)``). The plain difference ``Σ₂ − Σ₁`` would count the carried part
again (about ``d²·σ_yaw²`` after ``d`` metres), inflating the covariances of tracks coasting
out of view while the vehicle drives: on the tests' drive (10 runs of 25 m, heading σ 8° at
the end) the mean 2-dof NEES of corners and pillars is 1.44 and 1.23 with ``Σ₂ − Σ₁``, 1.86
and 1.60 with this (and in the thousands, with id switches, without drift noise). So
``ΔΣ = Σ₂ − F·Σ₁·Fᵀ``, made positive semi-definite (a covariance that shrinks, when a
controller fuses a fix, adds no noise).
"""

from __future__ import annotations

import numpy as np

from agent.arrays import FloatArray, wrap_angle


def rotation(yaw_rad: float) -> FloatArray:
    """(2, 2) rotation by ``yaw_rad`` (CCW)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s], [s, c]])


def points_to_odom(pose: FloatArray, points: FloatArray) -> FloatArray:
    """(k, 2) ``base_link`` points (m) to ``odom`` with ``pose`` = (x, y, yaw)."""
    return np.asarray(points @ rotation(float(pose[2])).T + pose[:2], dtype=np.float64)


def points_to_base(pose: FloatArray, points: FloatArray) -> FloatArray:
    """(k, 2) ``odom`` points (m) to ``base_link`` with ``pose`` = (x, y, yaw)."""
    return np.asarray((points - pose[:2]) @ rotation(float(pose[2])), dtype=np.float64)


def covariances_to_odom(pose: FloatArray, cov: FloatArray) -> FloatArray:
    """(k, 2, 2) point covariances (m²) rotated from ``base_link`` to ``odom``."""
    R = rotation(float(pose[2]))
    return np.asarray(R @ cov @ R.T, dtype=np.float64)


def lines_to_odom(
    pose: FloatArray, alpha_rad: FloatArray, rho_m: FloatArray, cov: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Lines (α, ρ) and their (k, 2, 2) covariances from ``base_link`` to ``odom``.

    ``α' = α + yaw``, ``ρ' = ρ + x·cos α' + y·sin α'``; the Jacobian over (α, ρ) is
    ``[[1, 0], [−x·sin α' + y·cos α', 1]]``. ρ' may come out negative (a line passing
    between the odom origin and the vehicle's position): that is left as it is, since the
    tracker compares lines to within a half turn (:func:`align_lines`).
    """
    x, y, yaw = (float(v) for v in pose)
    a = alpha_rad + yaw
    c, s = np.cos(a), np.sin(a)
    rho = rho_m + x * c + y * s
    g = -x * s + y * c
    J = np.zeros((alpha_rad.size, 2, 2))
    J[:, 0, 0] = 1.0
    J[:, 1, 0] = g
    J[:, 1, 1] = 1.0
    return wrap_angle(a), rho, np.asarray(J @ cov @ J.transpose(0, 2, 1), dtype=np.float64)


def align_lines(
    alpha_rad: FloatArray, rho_m: FloatArray, ref_alpha_rad: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The same lines written with α within a quarter turn of ``ref_alpha_rad``.

    (α, ρ) and (α + π, −ρ) are one line; flipping leaves the covariance unchanged except for
    the sign of the α-ρ term (callers flip it with the returned sign: see ``flip``).
    """
    flip = np.abs(wrap_angle(alpha_rad - ref_alpha_rad)) > 0.5 * np.pi
    a = np.where(flip, wrap_angle(alpha_rad + np.pi), alpha_rad)
    return a, np.where(flip, -rho_m, rho_m)


def pose_motion_jacobian(dx_m: float, dy_m: float) -> FloatArray:
    """(3, 3) ``F``: how a pose error at one pose carries to a pose ``(dx, dy)`` further on
    (both in ``odom``): a heading error ``δψ`` moves the later position by ``δψ·(−dy, dx)``."""
    return np.array([[1.0, 0.0, -dy_m], [0.0, 1.0, dx_m], [0.0, 0.0, 1.0]])


def pose_noise_increment(
    cov_then: FloatArray, cov_now: FloatArray, dx_m: float, dy_m: float
) -> FloatArray:
    """(3, 3) ``ΔΣ = Σ_now − F·Σ_then·Fᵀ``, clipped to positive semi-definite (module doc)."""
    F = pose_motion_jacobian(dx_m, dy_m)
    d = cov_now - F @ cov_then @ F.T
    d = 0.5 * (d + d.T)
    w, v = np.linalg.eigh(d)
    return np.asarray((v * np.clip(w, 0.0, None)) @ v.T, dtype=np.float64)


def point_drift_noise(
    points: FloatArray, vehicle_xy: FloatArray, delta_cov: FloatArray
) -> FloatArray:
    """(k, 2, 2) ``Q = J·ΔΣ·Jᵀ`` for points ``(k, 2)`` in ``odom`` (m), the vehicle at
    ``vehicle_xy`` and ``delta_cov`` (3, 3) over (x, y, yaw), or one per point (k, 3, 3).

    ``J = [I | L]`` with the lever arm ``L = (−(p_y − v_y), p_x − v_x)``
    (:func:`point_drift_jacobian`), written out so it costs a few array operations.
    """
    L = np.empty_like(points)
    L[:, 0] = vehicle_xy[1] - points[:, 1]
    L[:, 1] = points[:, 0] - vehicle_xy[0]
    d = np.broadcast_to(delta_cov, (points.shape[0], 3, 3))
    Lc = L[:, :, None] * d[:, None, :2, 2]
    return np.asarray(
        d[:, :2, :2]
        + Lc
        + Lc.transpose(0, 2, 1)
        + d[:, 2, 2, None, None] * L[:, :, None] * L[:, None, :],
        dtype=np.float64,
    )


def point_drift_jacobian(points: FloatArray, vehicle_xy: FloatArray) -> FloatArray:
    """(k, 2, 3) ∂(feature in ``odom``)/∂(vehicle pose x, y, yaw)."""
    J = np.zeros((points.shape[0], 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    J[:, 0, 2] = vehicle_xy[1] - points[:, 1]
    J[:, 1, 2] = points[:, 0] - vehicle_xy[0]
    return J


def line_drift_noise(
    alpha_rad: FloatArray, vehicle_xy: FloatArray, delta_cov: FloatArray
) -> FloatArray:
    """(k, 2, 2) ``Q = J·ΔΣ·Jᵀ`` (``delta_cov`` (3, 3), or (k, 3, 3) one per line) for
    lines (α, ρ) in ``odom``: ``J = [[0, 0, 1],
    [cos α, sin α, −v_x·sin α + v_y·cos α]]`` (ρ' = ρ_b + v·n(α_b + yaw))."""
    c, s = np.cos(alpha_rad), np.sin(alpha_rad)
    J = np.zeros((alpha_rad.size, 2, 3))
    J[:, 0, 2] = 1.0
    J[:, 1, 0] = c
    J[:, 1, 1] = s
    J[:, 1, 2] = -vehicle_xy[0] * s + vehicle_xy[1] * c
    return np.asarray(J @ delta_cov @ J.transpose(0, 2, 1), dtype=np.float64)
