"""Compiled loops of :mod:`agent.tracking.drift` (numba, see :mod:`agent.compiled`).

:func:`advance` is :func:`agent.sim.odometry.propagate` applied ``steps`` times to every
track's hypotheses with the same readings, and :func:`covariance` is
:meth:`agent.tracking.drift.RelativeDrift.covariance`; the tests compare each with its numpy
original (to rounding: :func:`advance` hoists what does not depend on the track). In numpy a
step costs some twenty array calls of a few microseconds each, whatever the number of
tracks.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled


@compiled
def advance(
    hyp: FloatArray,
    slip: FloatArray,
    left_m: float,
    right_m: float,
    errors: FloatArray,
    track_m: float,
    slip_m: float,
    steps: int,
) -> None:
    """Move ``hyp`` (k, h, 3) and ``slip`` (k, 3, 3) in place by ``steps`` steps of the
    encoder readings ``left_m``, ``right_m`` (the same for every track), under the
    hypotheses ``errors`` (h, 3) of ``(δ_L, δ_R, δ_b)``: :func:`agent.sim.odometry.propagate`.

    A hypothesis's step length, turn and chord factor depend on the readings and its
    errors only, not on the track: they are worked out once, and a step of a track's
    hypothesis is one sine and one cosine. The slip's ``F·S·Fᵀ + G·Q·Gᵀ`` is written out
    (``F`` is the identity but for its yaw column).
    """
    k, h = hyp.shape[0], hyp.shape[1]
    b = track_m
    ds_k = np.empty(h)  # step length times chord factor
    half = np.empty(h)
    turn = np.empty(h)
    for j in range(h):
        a = (1.0 + errors[j, 0]) * left_m
        c = (1.0 + errors[j, 1]) * right_m
        dth = (c - a) / (b * (1.0 + errors[j, 2]))
        hh = 0.5 * dth
        kk = 1.0 - hh * hh / 6.0 if abs(hh) < 1e-6 else math.sin(hh) / hh
        ds_k[j] = 0.5 * (a + c) * kk
        half[j] = hh
        turn[j] = dth
    # The slip about hypothesis 0 (its pose before the step).
    a0 = (1.0 + errors[0, 0]) * left_m
    c0 = (1.0 + errors[0, 1]) * right_m
    s0 = 0.5 * (a0 + c0)
    h0 = half[0]
    if abs(h0) < 1e-6:
        k0 = 1.0 - h0 * h0 / 6.0
        dk0 = -h0 / 3.0
    else:
        k0 = math.sin(h0) / h0
        dk0 = (h0 * math.cos(h0) - math.sin(h0)) / (h0 * h0)
    q0, q1 = slip_m * abs(a0), slip_m * abs(c0)
    for _ in range(steps):
        for r in range(k):
            phi0 = hyp[r, 0, 2] + h0
            cp, sp = math.cos(phi0), math.sin(phi0)
            # G = ∂(pose)/∂(readings): the arc's Jacobian in (Δs, Δθ) times ∂(Δs, Δθ)/∂(L, R).
            m00, m10 = k0 * cp, k0 * sp
            m01 = s0 * 0.5 * (dk0 * cp - k0 * sp)
            m11 = s0 * 0.5 * (dk0 * sp + k0 * cp)
            g00, g01 = 0.5 * m00 - m01 / b, 0.5 * m00 + m01 / b
            g10, g11 = 0.5 * m10 - m11 / b, 0.5 * m10 + m11 / b
            g20, g21 = -1.0 / b, 1.0 / b
            f0, f1 = -s0 * k0 * sp, s0 * k0 * cp  # F's yaw column (x, y rows)
            S = slip[r]
            # F·S: rows x and y gain f·(row yaw); then (F·S)·Fᵀ: columns alike.
            for c in range(3):
                S[0, c] += f0 * S[2, c]
                S[1, c] += f1 * S[2, c]
            for i in range(3):
                S[i, 0] += f0 * S[i, 2]
                S[i, 1] += f1 * S[i, 2]
            g0 = (g00, g10, g20)
            g1 = (g01, g11, g21)
            for i in range(3):
                for c in range(3):
                    S[i, c] += g0[i] * q0 * g0[c] + g1[i] * q1 * g1[c]
            for j in range(h):
                phi = hyp[r, j, 2] + half[j]
                hyp[r, j, 0] += ds_k[j] * math.cos(phi)
                hyp[r, j, 1] += ds_k[j] * math.sin(phi)
                hyp[r, j, 2] += turn[j]


@compiled
def covariance(hyp: FloatArray, slip: FloatArray, weights: FloatArray) -> FloatArray:
    """(k, 3, 3) the hypotheses' weighted spread about hypothesis 0 plus ``slip``,
    symmetrised: :meth:`agent.tracking.drift.RelativeDrift.covariance`."""
    k, h = hyp.shape[0], hyp.shape[1]
    out = np.empty((k, 3, 3))
    for r in range(k):
        P = np.zeros((3, 3))
        for j in range(1, h):
            w = weights[j]
            for a in range(3):
                da = hyp[r, j, a] - hyp[r, 0, a]
                for c in range(3):
                    P[a, c] += w * da * (hyp[r, j, c] - hyp[r, 0, c])
        for a in range(3):
            for c in range(3):
                out[r, a, c] = 0.5 * ((P[a, c] + slip[r, a, c]) + (P[c, a] + slip[r, c, a]))
    return out


def warm_up() -> None:
    """Compile (or load) both kernels."""
    hyp = np.zeros((1, 2, 3))
    slip = np.zeros((1, 3, 3))
    errors = np.zeros((2, 3))
    advance(hyp, slip, 0.01, 0.01, errors, 0.5, 1e-5, 1)
    covariance(hyp, slip, np.array([0.5, 0.5]))
