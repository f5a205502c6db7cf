"""The wheel odometry's compiled step (:class:`agent.sim.odometry.WheelOdometry`; why
compiled: :mod:`agent.compiled`).

The world simulator advances the odometry once or twice a tick, a step each: in numpy
(:func:`agent.sim.odometry.encoder_readings` and :func:`agent.sim.odometry.propagate`) some
fifty calls on arrays of 125 hypotheses and 3×3 matrices, about 0.1 ms a step. Here the
readings, the hypotheses' motion and the slip's Jacobians are one pass, with those
functions' arithmetic in their order; the products of
3×3 matrices stay numpy's (its BLAS sums with fused multiply-adds, which plain code would
not reproduce to the bit), so that the odometry, and so an evaluation's records, are the
same whichever ran.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled


@compiled
def move_hypotheses(
    poses: FloatArray,
    true_left_m: FloatArray,
    true_right_m: FloatArray,
    true_errors: FloatArray,
    normal: FloatArray,
    errors: FloatArray,
    track_m: float,
    slip_m: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """One step of the odometry: :func:`agent.sim.odometry.encoder_readings`, then
    :func:`agent.sim.odometry.propagate` but for its matrix products.

    Parameters
    ----------
    poses
        (r, h, 3) each run's hypotheses' poses; hypothesis 0 the nominal one.
    true_left_m, true_right_m
        (r,) how far each run's wheels truly rolled over the step, metres.
    true_errors
        (r, 3) each run's true ``(δ_L, δ_R, δ_b)``.
    normal
        (r, 2) standard normal draws for the slip of each wheel.
    errors
        (h, 3) each hypothesis' ``(δ_L, δ_R, δ_b)``.
    track_m, slip_m
        Nominal track (m) and slip variance per metre rolled (m²/m).

    Returns
    -------
    poses, j_motion, F, q, distance_m, turn_rad
        (r, h, 3) after the step; (r, 3, 2) ``d(x, y, yaw)/d(Δs, Δθ)`` and (r, 3, 3) the
        pose's Jacobian ``F``, about the nominal hypothesis; (r, 2) the wheels' slip
        variances; (r,) the nominal hypothesis' arc length (m) and turn (rad).
    """
    r, h = poses.shape[0], poses.shape[1]
    out = np.empty_like(poses)
    j_motion = np.zeros((r, 3, 2))
    F = np.zeros((r, 3, 3))
    q = np.empty((r, 2))
    distance = np.empty(r)
    turn = np.empty(r)
    s0 = k0 = dk0 = c0 = n0 = a0 = cc0 = 0.0
    for i in range(r):
        # The encoders' readings u = (s - w)/(1 + δ), w = sqrt(slip_m·|s|)·normal.
        left, right = true_left_m[i], true_right_m[i]
        w_left = math.sqrt(slip_m * abs(left)) * normal[i, 0]
        w_right = math.sqrt(slip_m * abs(right)) * normal[i, 1]
        left_m = (left - w_left) / (1.0 + true_errors[i, 0])
        right_m = (right - w_right) / (1.0 + true_errors[i, 1])
        for j in range(h):
            a = (1.0 + errors[j, 0]) * left_m
            c = (1.0 + errors[j, 1]) * right_m
            ds = 0.5 * (a + c)
            dth = (c - a) / (track_m * (1.0 + errors[j, 2]))
            half = 0.5 * dth
            if abs(half) < 1e-6:  # the chord factor k = sin(half)/half and dk/dhalf
                k = 1.0 - half * half / 6.0
                dk = -half / 3.0
            else:
                k = math.sin(half) / half
                dk = (half * math.cos(half) - math.sin(half)) / (half * half)
            phi = poses[i, j, 2] + 0.5 * dth
            cos_phi, sin_phi = math.cos(phi), math.sin(phi)
            out[i, j, 0] = poses[i, j, 0] + ds * k * cos_phi
            out[i, j, 1] = poses[i, j, 1] + ds * k * sin_phi
            out[i, j, 2] = poses[i, j, 2] + dth
            if j == 0:
                s0, k0, dk0, c0, n0, a0, cc0 = ds, k, dk, cos_phi, sin_phi, a, c
                turn[i] = dth
        distance[i] = s0
        j_motion[i, 0, 0], j_motion[i, 1, 0] = k0 * c0, k0 * n0
        j_motion[i, 0, 1] = s0 * 0.5 * (dk0 * c0 - k0 * n0)
        j_motion[i, 1, 1] = s0 * 0.5 * (dk0 * n0 + k0 * c0)
        j_motion[i, 2, 1] = 1.0
        F[i, 0, 0] = F[i, 1, 1] = F[i, 2, 2] = 1.0
        F[i, 0, 2], F[i, 1, 2] = -s0 * k0 * n0, s0 * k0 * c0
        q[i, 0], q[i, 1] = slip_m * abs(a0), slip_m * abs(cc0)
    return out, j_motion, F, q, distance, turn
