"""The compiled loops of motion compensation (:mod:`agent.perception.filtering.placement`):
the vehicle pose and state age at each sample's time, and each sample placed with that pose
(why compiled: :mod:`agent.compiled`; in numpy the poses and the state age cost about 40 µs
a scan in call overhead). The tests check the look-up against ``numpy.interp``.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled


@compiled
def poses_and_age(
    states: FloatArray, t: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """Vehicle poses at times ``t`` and the largest state age over them (see
    ``agent.perception.filtering.placement.PoseHistory``).

    ``states`` is (k ≥ 1, 6): rows (t, x, y, yaw, speed, yaw rate), stamps strictly
    increasing, yaw unwrapped; ``t`` is (n,), s, in any order. Between two states the pose is
    interpolated linearly (as ``numpy.interp``); before the first or after the last it
    follows that end state's arc of constant speed ``v`` and yaw rate ``w`` over
    ``dt = t − t_end``: ``yaw = yaw_end + w·dt``, ``x = x_end + v/w·(sin yaw − sin yaw_end)``,
    ``y = y_end − v/w·(cos yaw − cos yaw_end)`` (a straight line for ``|w| < 1e-9``). A
    time's state age is the time since the newest state at or before it, or, before the
    first, the time until the first. Returns x (n,), y (n,), yaw (n,), m and rad, in
    ``odom``, and the largest age, s (0 for n = 0).
    """
    n = t.size
    k = states.shape[0]
    x = np.empty(n)
    y = np.empty(n)
    yaw = np.empty(n)
    ts = states[:, 0]
    after = np.searchsorted(ts, t, side="right")  # how many states are at or before t[i]
    oldest_age = 0.0
    for i in range(n):
        j = after[i]
        if 0 < j < k:  # between states j-1 and j
            f = (t[i] - ts[j - 1]) / (ts[j] - ts[j - 1])
            x[i] = states[j - 1, 1] + f * (states[j, 1] - states[j - 1, 1])
            y[i] = states[j - 1, 2] + f * (states[j, 2] - states[j - 1, 2])
            yaw[i] = states[j - 1, 3] + f * (states[j, 3] - states[j - 1, 3])
            age = t[i] - ts[j - 1]
        else:  # past an end state: its arc
            e = 0 if j == 0 else k - 1
            dt = t[i] - ts[e]
            age = abs(dt)
            x0, y0, yaw0 = states[e, 1], states[e, 2], states[e, 3]
            v, w = states[e, 4], states[e, 5]
            yaw[i] = yaw0 + w * dt
            if abs(w) < 1e-9:
                x[i] = x0 + v * dt * math.cos(yaw0)
                y[i] = y0 + v * dt * math.sin(yaw0)
            else:
                x[i] = x0 + v / w * (math.sin(yaw[i]) - math.sin(yaw0))
                y[i] = y0 - v / w * (math.cos(yaw[i]) - math.cos(yaw0))
        oldest_age = max(oldest_age, age)
    return x, y, yaw, oldest_age


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
    """Load the placement kernels (compiling them on the first use on this machine)."""
    r = np.ones(8)
    poses_and_age(np.array([[0.0, 0.0, 0.0, 0.0, 1.0, 0.0], [1.0, 1.0, 0.0, 0.0, 1.0, 0.0]]), r)
    place_points(r, r, r, r, r, r, 1e-4, np.zeros(3), 0.1)
