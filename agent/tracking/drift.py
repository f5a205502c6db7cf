"""The odometry's error since each track's last update: the drift a coasting track must carry.

A static feature seen at ``t0`` and put at ``q`` in ``odom`` is, at ``t``, where the tracker
expects it only if the odometry's error did not change between ``t0`` and ``t``. What
matters is the error of the *relative* motion from ``t0`` to ``t``, not the error of the pose
at ``t`` (which also holds everything that went wrong before ``t0``): a heading error
made before ``t0`` moves ``odom`` as a whole and the track with it. Written with the
odometry's nominal pose ``P₀(t)`` and the pose ``Pᵢ(t)`` that a vehicle with other wheel
errors would have reached from the same encoder readings, starting from ``P₀(t0)``, the
track's error is ``P₀(t)∘Pᵢ(t)⁻¹(q) − q ≈ J·(P₀ − Pᵢ)``, ``J = [I | perp(q − x₀(t))]``, to first
order in the heading difference: the Jacobian the tracker already applies to pose noise
(:func:`agent.tracking.geometry.point_drift_noise`).

The odometry's error is mostly systematic (wheel scale, wheel ratio and track errors fixed
for a run: :mod:`agent.sim.odometry`), so the relative error's covariance cannot be had from
the published pose covariances: neither ``Σ(t) − Σ(t0)`` (a random walk's, too large for a
track updated a scan ago late in a run) nor ``(√Σ(t) − √Σ(t0))²`` (exact only while the
path runs straight: measured on ``bench tracking``, 30 scenes, static NEES 5.5 for 2 dof
with it, the lateral error a turn brings about missing). It is propagated here, per track,
from the same error model the odometry declares (:class:`agent.sim.odometry.
OdometryErrorModel`; on a real vehicle, its calibrated error figures): each track carries
``h`` hypotheses of the systematic errors (a Gauss-Hermite rule, :func:`agent.sim.odometry.
sigma_errors`) integrating the odometry's own motion since the track's last update, and
the slip's share, propagated linearly; :meth:`RelativeDrift.covariance` is their spread
about the nominal pose plus that share.

The odometry's motion between two scans is taken as one arc from the two poses the
tracker receives (encoder readings ``u = Δs ∓ b·Δθ/2`` for the nominal track ``b``), cut in
steps of at most :data:`agent.sim.odometry.MAX_STEP_M` and ``MAX_STEP_RAD``.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.sim.odometry import (
    MAX_STEP_M,
    MAX_STEP_RAD,
    OdometryErrorModel,
    propagate,
    sigma_errors,
)
from agent.tracking import drift_kernels

__all__ = ["POINTS_PER_AXIS", "RelativeDrift", "arc_between"]

POINTS_PER_AXIS = 3
"""Gauss-Hermite nodes per systematic error (27 hypotheses per track; the odometry itself
uses 5, 125, over whole runs of 10-15 m, where its heading spread reaches 0.3-0.45 rad; a
track's relative drift is over the metres since it was last seen, and 3 nodes integrate
polynomials up to degree 5 exactly at a fifth of the cost)."""


def arc_between(before: FloatArray, after: FloatArray) -> tuple[float, float]:
    """``(Δs, Δθ)``: the arc length (m, negative backwards) and turn (rad) of the single
    constant-curvature arc from pose ``before`` to pose ``after`` ((x, y, yaw) each)."""
    dx, dy = float(after[0] - before[0]), float(after[1] - before[1])
    dth = math.remainder(float(after[2] - before[2]), math.tau)
    chord = math.hypot(dx, dy)
    if chord == 0.0:
        return 0.0, dth
    h = 0.5 * dth
    k = 1.0 - h * h / 6.0 if abs(h) < 1e-6 else math.sin(h) / h  # chord over arc
    # Forward or backward: the chord's direction against the heading half way round.
    mid = float(before[2]) + h
    sign = 1.0 if dx * math.cos(mid) + dy * math.sin(mid) >= 0.0 else -1.0
    return sign * chord / k, dth


class RelativeDrift:
    """Per-track hypotheses of the odometry's error since each track's last update.

    Parameters
    ----------
    model
        The odometry's error model (track, systematic spreads, slip).
    points_per_axis
        Gauss-Hermite nodes per systematic error (:data:`POINTS_PER_AXIS`).

    The state of ``k`` tracks is two arrays the caller keeps with its tracks:
    ``hyp`` (k, h, 3) poses in ``odom``, hypothesis 0 the nominal one, and ``slip``
    (k, 3, 3) the slip's share of the covariance; :meth:`start` makes them for tracks
    updated at a pose, :meth:`advance` moves them with the odometry, :meth:`covariance`
    reads them.
    """

    def __init__(self, model: OdometryErrorModel | None = None, points_per_axis: int = 3):
        self.model = model if model is not None else OdometryErrorModel()
        self.errors, self.weights = sigma_errors(self.model, points_per_axis)

    @property
    def hypotheses(self) -> int:
        """``h``, the hypotheses per track."""
        return int(self.weights.size)

    def start(self, pose: FloatArray, n: int) -> tuple[FloatArray, FloatArray]:
        """``(hyp, slip)`` for ``n`` tracks last updated at the odometry pose ``pose``."""
        hyp = np.broadcast_to(np.asarray(pose, dtype=np.float64)[:3], (n, self.hypotheses, 3))
        return hyp.copy(), np.zeros((n, 3, 3))

    def _readings(self, before: FloatArray, after: FloatArray) -> tuple[float, float, int] | None:
        """The encoder readings (left, right, m) of each of the ``n`` steps of the arc from
        ``before`` to ``after``, and ``n``; None when the vehicle did not move."""
        ds, dth = arc_between(before, after)
        if ds == 0.0 and dth == 0.0:
            return None
        n = max(1, math.ceil(max(abs(ds) / MAX_STEP_M, abs(dth) / MAX_STEP_RAD)))
        b = self.model.track_m
        return (ds - 0.5 * b * dth) / n, (ds + 0.5 * b * dth) / n, n

    def advance(
        self, hyp: FloatArray, slip: FloatArray, before: FloatArray, after: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Every track's hypotheses moved by the odometry's motion from pose ``before`` to
        pose ``after`` (one arc, in steps; module docstring)."""
        steps = self._readings(before, after)
        if hyp.shape[0] == 0 or steps is None:
            return hyp, slip
        hyp = np.ascontiguousarray(hyp, dtype=np.float64).copy()
        slip = np.ascontiguousarray(slip, dtype=np.float64).copy()
        self.advance_in_place(hyp, slip, before, after)
        return hyp, slip

    def advance_in_place(
        self, hyp: FloatArray, slip: FloatArray, before: FloatArray, after: FloatArray
    ) -> None:
        """:meth:`advance` on C-contiguous float64 ``hyp`` and ``slip``, in place."""
        steps = self._readings(before, after)
        if hyp.shape[0] == 0 or steps is None:
            return
        left, right, n = steps
        drift_kernels.advance(
            hyp, slip, left, right, self.errors, self.model.track_m, self.model.slip_m, n
        )

    def advance_reference(
        self, hyp: FloatArray, slip: FloatArray, before: FloatArray, after: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """:meth:`advance` in numpy, with :func:`agent.sim.odometry.propagate` (the tests'
        reference for the compiled loop)."""
        k = hyp.shape[0]
        steps = self._readings(before, after)
        if k == 0 or steps is None:
            return hyp, slip
        left, right, n = steps
        for _ in range(n):
            hyp, slip, _, _ = propagate(
                hyp, slip, np.full(k, left), np.full(k, right), self.errors, self.model
            )
        return hyp, slip

    def covariance(self, hyp: FloatArray, slip: FloatArray) -> FloatArray:
        """(k, 3, 3) the covariance of the pose error since each track's last update: the
        hypotheses' spread about the nominal one (yaw difference unwrapped) plus the slip's
        share."""
        if hyp.shape[0] == 0:
            return np.zeros((0, 3, 3))
        return drift_kernels.covariance(
            np.ascontiguousarray(hyp, dtype=np.float64),
            np.ascontiguousarray(slip, dtype=np.float64),
            self.weights,
        )

    def covariance_reference(self, hyp: FloatArray, slip: FloatArray) -> FloatArray:
        """:meth:`covariance` in numpy (the tests' reference for the compiled loop)."""
        d = hyp[:, 1:] - hyp[:, :1]
        P: FloatArray = np.einsum("h,khi,khj->kij", self.weights[1:], d, d) + slip
        return 0.5 * (P + np.swapaxes(P, 1, 2))
