"""The compiled loop of motion compensation (:mod:`agent.perception.filtering.placement`):
each sample placed with the pose at its own time (why compiled: :mod:`agent.compiled`).
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled


@compiled
def place_points(
    x: FloatArray,
    y: FloatArray,
    yaw: FloatArray,
    beam_rad: FloatArray,
    range_m: FloatArray,
    sigma_m: FloatArray,
    scan_angle_sigma_rad: float,
    reference: FloatArray,
    mount_offset_m: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Samples placed in the vehicle frame at the reference pose (see
    ``agent.perception.filtering.placement.place_samples``).

    Sample i's beam leaves the centre of scanning, ``mount_offset_m`` ahead of the vehicle
    pose (x_i, y_i, yaw_i) at its own time, at ``yaw_i + beam_rad_i`` (pan plus scan angle),
    odometry frame; ``reference`` is the vehicle pose (x, y, yaw) the output is relative
    to. Returns points (n, 2), their covariances (n, 2, 2) (``σ_r²`` along the beam,
    ``(r·σ_θ)²`` across it), the centres of scanning (n, 2) and the beams' headings (n,),
    all in the vehicle frame at the reference pose.
    """
    n = x.size
    points = np.empty((n, 2))
    cov = np.empty((n, 2, 2))
    origin = np.empty((n, 2))
    heading = np.empty(n)
    rx, ry, ryaw = reference[0], reference[1], reference[2]
    c, s = math.cos(ryaw), math.sin(ryaw)
    for i in range(n):
        ox = x[i] + mount_offset_m * math.cos(yaw[i]) - rx
        oy = y[i] + mount_offset_m * math.sin(yaw[i]) - ry
        h_odom = yaw[i] + beam_rad[i]
        px = ox + range_m[i] * math.cos(h_odom)
        py = oy + range_m[i] * math.sin(h_odom)
        origin[i, 0], origin[i, 1] = c * ox + s * oy, -s * ox + c * oy
        points[i, 0], points[i, 1] = c * px + s * py, -s * px + c * py
        h = h_odom - ryaw
        ax, ay = math.cos(h), math.sin(h)
        var_along = sigma_m[i] * sigma_m[i]
        across = range_m[i] * scan_angle_sigma_rad
        var_across = across * across
        cov[i, 0, 0] = var_along * ax * ax + var_across * ay * ay
        cov[i, 0, 1] = cov[i, 1, 0] = (var_along - var_across) * ax * ay
        cov[i, 1, 1] = var_along * ay * ay + var_across * ax * ax
        heading[i] = h
    return points, cov, origin, heading


def warm_up() -> None:
    """Load the placement kernel (compiling it on the first use on this machine)."""
    r = np.ones(8)
    place_points(r, r, r, r, r, r, 1e-4, np.zeros(3), 0.1)
