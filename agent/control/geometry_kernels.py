"""The compiled arithmetic of the arc planner's motions (:mod:`agent.control.local_planner`,
poses by the equations of :mod:`agent.control.geometry`).

Per command the planner takes its twenty arcs through a score of small steps (scaled
twists, how far each goes, its end pose in ``odom``, the heading error there, the score and
the best) and rolls the best one out: about forty numpy operations on 20-element arrays,
2-8 µs each whatever their size, 0.26 ms a command in all (measured on the random rooms of
``evaluate``; 0.05 ms here). Three loops do the same arithmetic in the same order of
operations:

* :func:`arc_ends` scales the twists and finds where each arc ends;
* :func:`arc_scores` scores the ends and picks the best (the bearing to the target comes
  in from numpy's ``arctan2``, which is not libm's ``atan2`` to the last bit);
* :func:`arc_rollout` rolls the best arc out at evenly spaced displacements.

The tests compare them with the numpy formulation in
:func:`agent.control.local_planner.choose_reference`.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled, compiled_inline

NOWHERE_M = 1e-3  # unsticking, an arc that ends nearer its start than this is no move


@compiled_inline
def _sign(x: float) -> float:
    """``np.sign``: −1, 0 or 1, NaN for NaN."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return x


@compiled
def arc_ends(
    v: FloatArray,
    w: FloatArray,
    lam: FloatArray,
    d_free: FloatArray,
    v_unit: FloatArray,
    w_unit: FloatArray,
    rotation: BoolArray,
    radius_m: float,
    horizon_s: float,
    turn_rad: float,
    x: float,
    y: float,
    yaw: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """Per motion (m,): the scaled twist ``lam·(v, w)``, its unit speed
    ``u = |v| + r·|w|``, how far its arc goes over ``horizon_s`` (no further than ``d_free``;
    a rotation toward ``turn_rad``, the sign of its ``w_unit``, stops when it faces that way)
    and where it ends from the pose ``(x, y, yaw)``: ``(v_c, w_c, u, d_end, end, end_yaw)``
    with ``end`` (m, 2) ``odom``. A straight arc (|ŵ| < 1e-9) ends at ``y = 0`` in
    ``base_link``."""
    m = v.shape[0]
    v_c = np.empty(m)
    w_c = np.empty(m)
    u = np.empty(m)
    d_end = np.empty(m)
    end = np.empty((m, 2))
    end_yaw = np.empty(m)
    rot_d = abs(turn_rad) * radius_m
    turn_sign = _sign(turn_rad)
    c, s = math.cos(yaw), math.sin(yaw)
    for j in range(m):
        v_c[j] = lam[j] * v[j]
        w_c[j] = lam[j] * w[j]
        u[j] = abs(v_c[j]) + radius_m * abs(w_c[j])
        d = min(u[j] * horizon_s, d_free[j])
        if rotation[j] and _sign(w_unit[j]) == turn_sign:
            d = min(d, rot_d)
        d_end[j] = d
        mv, mw = v_unit[j], w_unit[j]
        th = mw * d
        if abs(mw) < 1e-9:
            ex, ey = mv * d, 0.0
        else:
            ex = mv * math.sin(th) / mw
            ey = mv * (1.0 - math.cos(th)) / mw
        end[j, 0] = x + c * ex - s * ey
        end[j, 1] = y + s * ex + c * ey
        end_yaw[j] = yaw + th
    return v_c, w_c, u, d_end, end, end_yaw


@compiled
def arc_scores(
    end: FloatArray,
    end_yaw: FloatArray,
    cost: FloatArray,
    bearing: FloatArray,
    descent: FloatArray,
    u: FloatArray,
    d_free: FloatArray,
    d_end: FloatArray,
    rotation: BoolArray,
    reverse: BoolArray,
    target_x: float,
    target_y: float,
    near_m: float,
    max_speed_m_s: float,
    max_yaw_rate_rad_s: float,
    heading_weight: float,
    clearance_weight: float,
    clearance_want_m: float,
    reverse_penalty_s: float,
    unstick: bool,
    extra_s: FloatArray,
) -> tuple[int, bool]:
    """The index of the lowest score (the first such; the first NaN, as ``np.argmin``) and
    whether any motion moves (``u > 1e-6``). Score of an arc ending at ``end`` (m, 2),
    ``end_yaw`` (m,), where
    the field's cost-to-go is ``cost``: as the module docstring of
    :mod:`agent.control.local_planner`; the wanted heading is ``bearing`` (the bearing to
    the target) unless the end lies within ``near_m`` of the target, then ``descent``;
    ``extra_s`` (m,) is added to every score (the walks' charge). Unsticking, a motion
    whose arc ends where it starts (``d_end`` (m,) under 1 mm: a rotation toward a way it
    already faces) is no move."""
    best, best_j = 0, math.inf
    moving_any = False
    for j in range(end.shape[0]):
        dx, dy = target_x - end[j, 0], target_y - end[j, 1]
        theta_star = bearing[j] if math.hypot(dx, dy) > near_m else descent[j]
        error = abs((end_yaw[j] - theta_star + math.pi) % (2.0 * math.pi) - math.pi)
        J = cost[j] / max_speed_m_s + heading_weight * error / max_yaw_rate_rad_s + extra_s[j]
        moving = u[j] > 1e-6
        moving_any = moving_any or moving
        if unstick:
            if not moving or d_end[j] < NOWHERE_M:
                J = math.inf
        else:
            tight = 1.0 if moving and not rotation[j] else 0.0
            back = 1.0 if reverse[j] else 0.0
            J = J + (
                clearance_weight * max(0.0, clearance_want_m - d_free[j]) * tight
                + reverse_penalty_s * back
            )
        # np.argmin: the first smallest, or the first NaN.
        if j == 0 or (math.isnan(J) and not math.isnan(best_j)) or best_j > J:
            best, best_j = j, J
    return best, moving_any


@compiled_inline
def arc_offset(v: float, w: float, d: float) -> tuple[float, float, float]:
    """``(x, y, θ)`` of the unit motion ``(v, w)`` after displacement ``d``, in the frame it
    started from: :func:`agent.control.geometry.motion_poses` (to first order in ``w·d``
    where ``|w|`` < 1e-9)."""
    th = w * d
    if abs(w) < 1e-9:
        return v * d, 0.5 * v * w * d * d, th
    return v * math.sin(th) / w, v * (1.0 - math.cos(th)) / w, th


@compiled
def arc_rollout(
    v_unit: float, w_unit: float, d: float, count: int, x: float, y: float, yaw: float
) -> FloatArray:
    """The points (count, 2) in ``odom`` of the motion ``(v_unit, w_unit)`` from the pose
    ``(x, y, yaw)`` at ``count`` displacements evenly spaced over ``(0, d]``: those of
    ``np.linspace(0, d, count + 1)[1:]`` (its arithmetic: ``i·(d/count)``, the last ``d``
    itself), poses by :func:`agent.control.geometry.motion_poses`."""
    out = np.empty((count, 2))
    step = d / count
    c, s = math.cos(yaw), math.sin(yaw)
    for i in range(1, count + 1):
        if i == count:
            di = d
        elif step == 0.0:
            di = i / count * d
        else:
            di = i * step
        px, py, _ = arc_offset(v_unit, w_unit, di)
        out[i - 1, 0] = x + c * px - s * py
        out[i - 1, 1] = y + s * px + c * py
    return out


def warm_up() -> None:
    """Load (or compile, on the first use on a machine) every kernel of this module, for the
    argument types :mod:`agent.control.local_planner` passes."""
    one = np.ones(1)
    flag = np.zeros(1, dtype=np.bool_)
    arc_ends(one, one, one, one, one, one, flag, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0)
    arc_scores(np.zeros((1, 2)), one, one, one, one, one, one, one, flag, flag, 0.0, 0.0, 0.05,
               0.5, 1.5, 0.3, 1.0, 0.5, 1.0, False, one)  # fmt: skip
    arc_rollout(1.0, 0.0, 1.0, 6, 0.0, 0.0, 0.0)
