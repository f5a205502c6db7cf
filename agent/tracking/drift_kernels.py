"""Compiled loops of :mod:`agent.tracking.drift` (numba, see :mod:`agent.compiled`).

:func:`advance` is :func:`agent.sim.odometry.propagate` applied ``steps`` times to every
track's hypotheses with the same readings, and :func:`covariance` is
:meth:`agent.tracking.drift.RelativeDrift.covariance`; each in the order of operations of its
numpy original, which the tests compare it with. In numpy a step costs some twenty array
calls of a few microseconds each, whatever the number of tracks.
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
    hypotheses ``errors`` (h, 3) of ``(δ_L, δ_R, δ_b)``: :func:`agent.sim.odometry.propagate`."""
    k, h = hyp.shape[0], hyp.shape[1]
    b = track_m
    for _ in range(steps):
        for r in range(k):
            # The slip about hypothesis 0, with its pose before the step.
            a0 = (1.0 + errors[0, 0]) * left_m
            c0 = (1.0 + errors[0, 1]) * right_m
            s0 = 0.5 * (a0 + c0)
            th0 = (c0 - a0) / (track_m * (1.0 + errors[0, 2]))
            half = 0.5 * th0
            if abs(half) < 1e-6:
                k0 = 1.0 - half * half / 6.0
                dk0 = -half / 3.0
            else:
                k0 = math.sin(half) / half
                dk0 = (half * math.cos(half) - math.sin(half)) / (half * half)
            phi0 = hyp[r, 0, 2] + half
            cp, sp = math.cos(phi0), math.sin(phi0)
            jm = np.zeros((3, 2))
            jm[0, 0], jm[1, 0] = k0 * cp, k0 * sp
            jm[0, 1] = s0 * 0.5 * (dk0 * cp - k0 * sp)
            jm[1, 1] = s0 * 0.5 * (dk0 * sp + k0 * cp)
            jm[2, 1] = 1.0
            jn = np.array([[0.5, 0.5], [-1.0 / b, 1.0 / b]])
            G = jm @ jn
            F = np.eye(3)
            F[0, 2], F[1, 2] = -s0 * k0 * sp, s0 * k0 * cp
            q0, q1 = slip_m * abs(a0), slip_m * abs(c0)
            GQ = np.empty((3, 2))
            for i in range(3):
                GQ[i, 0] = G[i, 0] * q0
                GQ[i, 1] = G[i, 1] * q1
            slip[r] = F @ slip[r] @ F.T + GQ @ G.T
            for j in range(h):
                a = (1.0 + errors[j, 0]) * left_m
                c = (1.0 + errors[j, 1]) * right_m
                ds = 0.5 * (a + c)
                dth = (c - a) / (track_m * (1.0 + errors[j, 2]))
                hh = 0.5 * dth
                kk = 1.0 - hh * hh / 6.0 if abs(hh) < 1e-6 else math.sin(hh) / hh
                phi = hyp[r, j, 2] + hh
                hyp[r, j, 0] += ds * kk * math.cos(phi)
                hyp[r, j, 1] += ds * kk * math.sin(phi)
                hyp[r, j, 2] += dth


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
