"""The world simulator's compiled motion (:class:`agent.stages.world_stage._Piece`; why
compiled: :mod:`agent.compiled`).

A tick integrates one or two pieces of motion of a step or two each and places the outline
at a few sub-steps of them: in numpy that was forty-odd calls on arrays of one to ten
elements, about 0.2 ms a tick. Each kernel here computes what the numpy formulation in the
tests (``tests/unit/stages/test_world_motion.py``) computes, in the same order of
operations, so that the two agree to the bit: the world's truth, and so an evaluation's
records, do not depend on which one ran.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled, compiled_inline

_SINC_TINY = float(np.finfo(np.float64).eps)
"""What :func:`numpy.sinc` puts in place of 0 (sin(x)/x at x = eps is exactly 1)."""


@compiled
def piece_nodes(
    x0: float,
    y0: float,
    yaw0: float,
    v0: float,
    w0: float,
    av: float,
    aw: float,
    duration: float,
    n: int,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """A piece of motion in ``n`` equal steps: speed ``v0 + av·t`` and yaw rate ``w0 + aw·t``
    over ``duration`` seconds from the pose ``(x0, y0, yaw0)``, each step the arc at its mean
    speed and yaw rate.

    Returns
    -------
    times, speed, yaw_rate, nodes
        (n + 1,) the steps' ends, seconds from the start; (n,) each step's mean speed (m/s)
        and yaw rate (rad/s); (n + 1, 3) the pose at each step's start, and the end.
    """
    times = np.empty(n + 1)
    for i in range(n + 1):
        times[i] = duration * float(i) / n
    speed = np.empty(n)
    yaw_rate = np.empty(n)
    nodes = np.empty((n + 1, 3))
    nodes[0, 0], nodes[0, 1], nodes[0, 2] = x0 + 0.0, y0 + 0.0, yaw0 + 0.0
    turned = dx_sum = dy_sum = 0.0  # running sums, as numpy's cumsum takes them
    for i in range(n):
        h = times[i + 1] - times[i]
        mid = times[i] + 0.5 * h
        speed[i] = v0 + av * mid
        yaw_rate[i] = w0 + aw * mid
        dx, dy = _arc(speed[i], yaw_rate[i], nodes[i, 2], h)
        step = yaw_rate[i] * h
        turned = step if i == 0 else turned + step
        dx_sum = dx if i == 0 else dx_sum + dx
        dy_sum = dy if i == 0 else dy_sum + dy
        nodes[i + 1, 0] = x0 + dx_sum
        nodes[i + 1, 1] = y0 + dy_sum
        nodes[i + 1, 2] = yaw0 + turned
    return times, speed, yaw_rate, nodes


@compiled
def piece_poses(
    times: FloatArray,
    speed: FloatArray,
    yaw_rate: FloatArray,
    nodes: FloatArray,
    v0: float,
    w0: float,
    av: float,
    aw: float,
    tau: FloatArray,
) -> FloatArray:
    """Poses (q, 3) ``tau`` (q,) seconds into a piece (:func:`piece_nodes`): along the arc of
    the step each falls in, the share of its distance truly gone (``v(t0)·dt + a·dt²/2`` of
    ``v_mean·h``) if the speed keeps its sign through the step, else the share of its turn
    if the yaw rate does, else of its time."""
    steps = speed.size
    ramps = av != 0.0 or aw != 0.0
    out = np.empty((tau.size, 3))
    for q in range(tau.size):
        count = 0
        for i in range(times.size):
            if times[i] <= tau[q]:
                count += 1
        i = min(max(count - 1, 0), steps - 1)
        start = times[i]
        dt = tau[q] - start
        h = times[i + 1] - start
        v, w = speed[i], yaw_rate[i]
        if ramps:
            share = dt / h
            w_start = w0 + aw * start
            w_end = w_start + aw * h
            # (w·h and v·h, not w and v, against 0: a rate so small that its product with h
            # underflows, as a fuzzed command's subnormal speed did, would divide by zero.)
            if w_start * w_end >= 0.0 and w * h != 0.0:
                share = (w_start * dt + 0.5 * aw * dt * dt) / (w * h)
            v_start = v0 + av * start
            v_end = v_start + av * h
            if v_start * v_end >= 0.0 and v * h != 0.0:
                share = (v_start * dt + 0.5 * av * dt * dt) / (v * h)
            dt = h * min(max(share, 0.0), 1.0)
        dx, dy = _arc(v, w, nodes[i, 2], dt)
        out[q, 0] = nodes[i, 0] + dx
        out[q, 1] = nodes[i, 1] + dy
        out[q, 2] = nodes[i, 2] + w * dt
    return out


@compiled
def piece_arcs(
    times: FloatArray, speed: FloatArray, yaw_rate: FloatArray, until: float
) -> FloatArray:
    """(k, 2) ``(distance_m, turn_rad)`` of each step's arc driven in the first ``until``
    seconds of a piece (:func:`piece_nodes`): the steps begun, the last cut short."""
    n = speed.size
    out = np.empty((n, 2))
    k = 0
    for i in range(n):
        h = min(times[i + 1] - times[i], max(until - times[i], 0.0))
        if h > 0.0:
            out[k, 0] = speed[i] * h
            out[k, 1] = yaw_rate[i] * h
            k += 1
    return out[:k]


@compiled_inline
def _arc(speed: float, yaw_rate: float, yaw: float, dt: float) -> tuple[float, float]:
    """Displacement (dx, dy) along an arc at constant ``speed`` and ``yaw_rate`` for ``dt``
    from heading ``yaw``: the chord, ``v·dt·sinc(θ/2)`` long at the mean heading (``θ =
    ω·dt``); ``sinc`` as :func:`numpy.sinc` computes it."""
    turn = yaw_rate * dt
    x = math.pi * (turn / (2.0 * math.pi))
    if x == 0.0:
        x = _SINC_TINY
    chord = speed * dt * (math.sin(x) / x)
    heading = yaw + 0.5 * turn
    return chord * math.cos(heading), chord * math.sin(heading)
