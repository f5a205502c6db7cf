"""The compiled loop of :func:`agent.control.obstacles.capsules_from_view`.

In numpy the capsules of a vector took about 25 whole-array operations on a handful of
obstacles, 80 µs a vector (measured over ``evaluate --random 12``), nearly all of it call
overhead (see :mod:`agent.compiled`); here one pass over the obstacles, with the same
floating-point operations in the same order as the numpy formulation
(:func:`agent.control.obstacles.capsules_from_view_reference`, which the tests compare it with
to the bit).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled

_SEGMENT, _CYLINDER, _DOCKING = 0, 3, 4  # agent.planning.environment's kinds


@compiled
def capsule_arrays(
    kind: NDArray[np.uint8],
    position_xy: FloatArray,
    velocity_xy: FloatArray,
    extent: FloatArray,
    covariance: FloatArray,
    across_sigma_m: FloatArray,
    mover_speed_m_s: float,
    significance: float,
    horizon_s: float,
    sigmas: float,
    cap_m: float,
    mover_cap_m: float,
    margin_m: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, BoolArray]:
    """``(a, b, radius, inflation, moving)`` of the capsules (module docstring of
    :mod:`agent.control.obstacles`): the covariance's position block (predicted to
    ``horizon_s`` for a mover) gives ``σ = √max(λ_max, 0)``, or for a static segment or
    docking target ``across_sigma_m`` where given (``(k,)``; empty: not given),
    ``inflation = min(sigmas·σ, cap) + margin_m`` with ``cap`` ``mover_cap_m`` for a mover,
    else ``cap_m`` (NaN propagating, as numpy's minimum does). A mover: speed ``s`` above
    ``mover_speed_m_s`` and ``s² > significance² · uᵀ P_vv u`` along its direction ``u``."""
    k = kind.size
    a = np.empty((k, 2))
    b = np.empty((k, 2))
    radius = np.empty(k)
    inflation = np.empty(k)
    moving = np.empty(k, dtype=np.bool_)
    t, tt = horizon_s, horizon_s * horizon_s
    across_given = across_sigma_m.size == k
    for i in range(k):
        segment = kind[i] == _SEGMENT or kind[i] == _DOCKING
        p = covariance[i]
        vx, vy = velocity_xy[i, 0], velocity_xy[i, 1]
        s2 = vx * vx + vy * vy
        along = vx * (p[2, 2] * vx + p[2, 3] * vy) + vy * (p[3, 2] * vx + p[3, 3] * vy)
        mover = math.sqrt(s2) > mover_speed_m_s and s2 * s2 > significance * significance * along
        moving[i] = mover
        if mover:  # P_pp + T (P_pv + P_vp) + T² P_vv
            p00 = p[0, 0] + t * (p[0, 2] + p[2, 0]) + tt * p[2, 2]
            p01 = p[0, 1] + t * (p[0, 3] + p[2, 1]) + tt * p[2, 3]
            p10 = p[1, 0] + t * (p[1, 2] + p[3, 0]) + tt * p[3, 2]
            p11 = p[1, 1] + t * (p[1, 3] + p[3, 1]) + tt * p[3, 3]
        else:
            p00, p01, p10, p11 = p[0, 0], p[0, 1], p[1, 0], p[1, 1]
        off = 0.5 * (p01 + p10)
        lam = 0.5 * (p00 + p11) + math.sqrt(0.25 * ((p00 - p11) * (p00 - p11)) + off * off)
        sigma = math.sqrt(lam if not lam < 0.0 else 0.0)
        if segment and not mover and across_given:
            sigma = across_sigma_m[i]
        grown = sigmas * sigma
        cap = mover_cap_m if mover else cap_m
        inflation[i] = (cap if grown > cap else grown) + margin_m
        if mover:
            a[i, 0], a[i, 1] = position_xy[i, 0], position_xy[i, 1]
            b[i, 0] = position_xy[i, 0] + velocity_xy[i, 0] * t
            b[i, 1] = position_xy[i, 1] + velocity_xy[i, 1] * t
            if segment:  # its midpoint, radius half its length, swept like a cylinder
                dx, dy = extent[i, 2] - extent[i, 0], extent[i, 3] - extent[i, 1]
                radius[i] = 0.5 * math.hypot(dx, dy)
            else:
                radius[i] = abs(extent[i, 0]) if kind[i] == _CYLINDER else 0.0
        else:
            if segment:
                a[i, 0], a[i, 1] = extent[i, 0], extent[i, 1]
                b[i, 0], b[i, 1] = extent[i, 2], extent[i, 3]
            else:
                a[i, 0], a[i, 1] = position_xy[i, 0], position_xy[i, 1]
                b[i, 0], b[i, 1] = position_xy[i, 0], position_xy[i, 1]
            radius[i] = abs(extent[i, 0]) if kind[i] == _CYLINDER else 0.0
    return a, b, radius, inflation, moving


def warm_up() -> None:
    """Load (or compile, on the first use on a machine) this module's kernel, for the argument
    types :func:`agent.control.obstacles.capsules_from_view` passes."""
    xy = np.zeros((1, 2))
    for across in (np.zeros(1), np.zeros(0)):
        capsule_arrays(np.zeros(1, dtype=np.uint8), xy, xy, np.zeros((1, 4)),
                       np.zeros((1, 4, 4)), across, 0.2, 0.5, 1.0, 3.0, 0.3, 1.5, 0.05)  # fmt: skip
