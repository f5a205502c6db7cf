"""Wheel odometry of the simulated differential-drive base: its drift, and an honest covariance.

Frames follow REP-103 (x forward, y left, yaw counter-clockwise); metres, radians. The
``odom`` frame is the world frame as it was when the odometry started: odometry starts at
the world's ``vehicle_pose`` with no error, so at the start ``odom`` and ``world`` coincide
and the difference between an odometry pose and the true pose (``world_truth``) is the
odometry's error.

The error model (after Chong & Kleeman 1997, "Accurate odometry and error modelling for a
mobile robot", ICRA, and Borenstein & Feng 1996, "Measurement and correction of systematic
odometry errors in mobile robots", IEEE Trans. Robotics and Automation 12(6), the UMBmark
paper). Each wheel's encoder reads a distance ``u``; the odometry believes the wheel rolled
``u`` and that the wheels are ``track_m`` apart. The truth differs in three systematic ways,
drawn once per run (a vehicle's wheels and load do not change during a drive), and one
random way:

* ``δ_L``, ``δ_R``: each wheel's scale error, the true distance per unit reading minus one
  (effective wheel diameter against nominal: tyre wear and compression, manufacturing).
  Drawn as a common part ``c ~ N(0, scale_sigma²)`` (the average diameter, which scales
  distance, Borenstein's ``E_s``) and a differential part ``d ~ N(0, ratio_sigma²)`` (the
  diameter ratio, which bends a straight drive into an arc, Borenstein's ``E_d``):
  ``δ_L = c - d/2``, ``δ_R = c + d/2``.
* ``δ_b``: the track error; the effective track (between the wheels' contact points, which
  move across the tyres' width) is ``track_m·(1 + δ_b)``, ``δ_b ~ N(0, track_sigma²)``
  (Borenstein's ``E_b``); it scales every turn.
* slip: each wheel's true travel differs from its scaled reading by zero-mean noise whose
  variance grows in proportion to the distance that wheel rolls, ``slip_m·|s|`` (Chong &
  Kleeman's non-systematic model), independent between wheels and between steps.

So a wheel that truly rolls ``s`` reads ``u = (s - w)/(1 + δ)``, ``w ~ N(0, slip_m·|s|)``.

Defaults, for a small differential-drive vehicle (0.8 m × 0.6 m, about the chapter's
Robosoft platform) before calibration:

* ``track_m`` 0.5 m: a 0.6 m wide body with its drive wheels inside it; the contact
  patches' centres lie about 0.05 m in from each side.
* ``scale_sigma`` 0.015: distance errors of 1.5 % (RMS) on a straight drive, and
  ``ratio_sigma`` 0.015: heading drift of ``ratio_sigma/track_m`` = 0.03 rad/m, 1.7 °/m
  (RMS), on a straight drive; ``track_sigma`` 0.02: turns over- or under-read by 2 %.
  UMBmark's point is that such errors of uncalibrated vehicles dominate odometry error and
  are systematic; these spreads put a run's drift in the 1-2 % of distance and 1-3 °/m of
  heading that uncalibrated small vehicles show. They are a modelling choice at that level,
  not figures copied from the papers.
* ``slip_m`` 1e-5 m (variance per metre of wheel travel): 3.2 mm per wheel after 1 m,
  10 mm after 10 m; heading random walk ``sqrt(2·slip_m·s)/track_m``, 1.6° after 10 m; on a
  smooth indoor floor the random part is the smaller one, as Chong & Kleeman found once the
  systematic errors were calibrated out.

The covariance (:func:`propagate`, :attr:`WheelOdometry.pose_covariance`). Because the
systematic errors are fixed for the run, the pose error grows in proportion to the distance
driven, with correlations that a random walk over the pose alone cannot express. The state
that explains it is the augmented ``(x, y, yaw, δ_L, δ_R, δ_b)``, whose parameter block
starts at the prior of the systematic errors and stays there (odometry alone never learns
them) while the pose block starts at zero (``odom`` is defined by the start pose). An
extended Kalman filter over that state, linearised about the nominal path, was measured
over-confident with these defaults: at 10 m its heading spread is 0.3 rad, the path is then
far from linear in the errors, and the mean NEES over 200 runs came out 4.7 for 3 degrees of
freedom (the 95 % interval is 2.67-3.35). So the systematic block is propagated through the
exact motion instead, by a Gauss-Hermite rule over the prior (:func:`sigma_errors`, 125
hypotheses): each is a vehicle with those errors integrating the same encoder readings, and
their weighted spread about the nominal path is the systematic share of the pose covariance.
The slip's share is propagated linearly (EKF-style) about the nominal path, where it is
small. The published pose is the nominal dead reckoning, and its covariance is the second
moment about it (so it covers the small bias the nonlinearity gives the truth's mean); the
3×3 pose covariance is what ``odometry`` publishes. Consistency (NEES) is asserted by the tests over
seeded runs. Measured over 20 seeds × 200 runs of a scripted drive with turns, the mean
NEES is 3.02 at 10 m and 2.98 at 15 m (3 is honest); the pose error is not Gaussian (a
heading error of 0.3 rad bends the position error into a banana), so the NEES has heavier
tails than chi-square and the mean of 200 runs falls outside chi-square's 95 % interval for
about 15 % of seeds at 10 m (35 % at 15 m), not 5 %.

Each step is integrated as an exact arc (constant curvature), so with no error the odometry
is the truth to rounding. Steps are cut to at most :data:`MAX_STEP_M` and
:data:`MAX_STEP_RAD` so that the linearisation holds however seldom the caller advances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent.arrays import FloatArray
from agent.sim.odometry_kernels import move_hypotheses

__all__ = [
    "MAX_STEP_M",
    "MAX_STEP_RAD",
    "OdometryErrorModel",
    "WheelOdometry",
    "encoder_readings",
    "propagate",
    "sigma_errors",
    "wheel_travel",
]

MAX_STEP_M = 0.05
"""Longest step (metres of travel) integrated at once: the linearisation's error over a
step is second order in its length and turn."""
MAX_STEP_RAD = 0.05
"""Largest turn (radians) integrated at once."""
POINTS_PER_AXIS = 5
"""Gauss-Hermite nodes per axis of the systematic errors (:func:`sigma_errors`)."""


@dataclass(frozen=True)
class OdometryErrorModel:
    """The odometry's error model (see the module docstring for each value's reason).

    Attributes
    ----------
    track_m
        Nominal distance between the drive wheels' contact points, metres, > 0.
    scale_sigma
        Standard deviation of the wheels' common scale error (fraction), >= 0.
    ratio_sigma
        Standard deviation of the right-minus-left scale error (fraction), >= 0.
    track_sigma
        Standard deviation of the effective track's relative error (fraction), >= 0.
    slip_m
        Variance of a wheel's random distance error per metre it rolls, m²/m, >= 0.
    """

    track_m: float = 0.5
    scale_sigma: float = 0.015
    ratio_sigma: float = 0.015
    track_sigma: float = 0.02
    slip_m: float = 1e-5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.track_m) and self.track_m > 0.0):
            raise ValueError(f"track_m must be finite and > 0, got {self.track_m!r}")
        for name in ("scale_sigma", "ratio_sigma", "track_sigma", "slip_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value < 0.5):
                raise ValueError(f"{name} must be finite, >= 0 and < 0.5, got {value!r}")

    def prior(self) -> FloatArray:
        """(3, 3) covariance of the systematic errors ``(δ_L, δ_R, δ_b)``."""
        common, half_ratio = self.scale_sigma**2, 0.25 * self.ratio_sigma**2
        return np.array(
            [
                [common + half_ratio, common - half_ratio, 0.0],
                [common - half_ratio, common + half_ratio, 0.0],
                [0.0, 0.0, self.track_sigma**2],
            ]
        )


def wheel_travel(
    distance_m: npt.ArrayLike, turn_rad: npt.ArrayLike, track_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Distances the left and right wheels roll, metres, for a step of the base.

    Parameters
    ----------
    distance_m
        Arc length the base's centre travels (negative backwards), metres.
    turn_rad
        Change of yaw, radians, counter-clockwise.
    track_m
        The wheels' true distance apart, metres.
    """
    s, dth, b = (np.asarray(v, dtype=np.float64) for v in (distance_m, turn_rad, track_m))
    return s - 0.5 * b * dth, s + 0.5 * b * dth


def encoder_readings(
    left_m: FloatArray,
    right_m: FloatArray,
    errors: FloatArray,
    slip_m: float,
    normal: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """What the encoders read, metres, for wheels that truly rolled ``left_m``, ``right_m``.

    Parameters
    ----------
    left_m, right_m
        (r,) true wheel travel.
    errors
        (r, 3) the systematic errors ``(δ_L, δ_R, δ_b)``.
    slip_m
        Slip variance per metre rolled, m²/m.
    normal
        (r, 2) standard normal draws for the slip of each wheel.

    Returns
    -------
    left, right
        (r,) readings ``u = (s - w)/(1 + δ)``, ``w = sqrt(slip_m·|s|)·normal``.
    """
    w_left = np.sqrt(slip_m * np.abs(left_m)) * normal[:, 0]
    w_right = np.sqrt(slip_m * np.abs(right_m)) * normal[:, 1]
    return (left_m - w_left) / (1.0 + errors[:, 0]), (right_m - w_right) / (1.0 + errors[:, 1])


def _chord_factor(half_turn: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``k = sin(h)/h`` (chord over arc length for a turn of ``2h``) and ``dk/dh``."""
    small = np.abs(half_turn) < 1e-6
    h = np.where(small, 1.0, half_turn)
    k = np.where(small, 1.0 - half_turn**2 / 6.0, np.sin(h) / h)
    dk = np.where(small, -half_turn / 3.0, (h * np.cos(h) - np.sin(h)) / (h * h))
    return k, dk


def sigma_errors(
    model: OdometryErrorModel, points_per_axis: int = POINTS_PER_AXIS
) -> tuple[FloatArray, FloatArray]:
    """Hypotheses of the systematic errors and their weights: a Gauss-Hermite rule.

    The prior is Gaussian in 3 dimensions; the rule takes ``points_per_axis`` (odd; by
    default :data:`POINTS_PER_AXIS`, 5) nodes along each axis of a square root of it, 125
    in all, and integrates every polynomial of degree up to 9 (``2n - 1``) in each axis
    exactly. The unscented transform's 7 points (degree 3) were
    measured too few: the pose is far from linear in the errors at 10-15 m (its heading
    spread reaches 0.3-0.45 rad), and the mean NEES came out 3.14 at 10 m and 3.47 at 15 m
    over thousands of runs; with this rule 3.02 and 2.98.

    Returns
    -------
    points, weights
        (n³, 3) ``(δ_L, δ_R, δ_b)``, row 0 the nominal (all zero); (n³,) weights summing
        to 1.
    """
    if points_per_axis < 1 or points_per_axis % 2 == 0:
        raise ValueError(f"points_per_axis must be odd and positive, got {points_per_axis}")
    nodes, node_weights = np.polynomial.hermite_e.hermegauss(points_per_axis)
    node_weights = node_weights / node_weights.sum()
    grid = np.stack(np.meshgrid(nodes, nodes, nodes, indexing="ij"), axis=-1).reshape(-1, 3)
    weights = np.prod(
        np.stack(np.meshgrid(node_weights, node_weights, node_weights, indexing="ij"), -1),
        axis=-1,
    ).reshape(-1)
    first = int(np.argmin(np.abs(grid).sum(axis=1)))  # the centre node: the nominal
    order = np.concatenate([[first], np.delete(np.arange(grid.shape[0]), first)])
    points = grid[order] @ _sqrt_psd(model.prior()).T
    points[0] = 0.0  # exactly
    return np.asarray(points, dtype=np.float64), np.asarray(weights[order], dtype=np.float64)


def propagate(
    poses: FloatArray,
    slip_cov: FloatArray,
    left_m: FloatArray,
    right_m: FloatArray,
    errors: FloatArray,
    model: OdometryErrorModel,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One step of the odometry for ``r`` runs, each under ``h`` hypotheses of its errors.

    Parameters
    ----------
    poses
        (r, h, 3) ``(x_m, y_m, yaw_rad)`` in ``odom``, one per hypothesis; hypothesis 0 is
        the nominal one, the odometry's own estimate.
    slip_cov
        (r, 3, 3) the slip's share of the pose covariance, about hypothesis 0.
    left_m, right_m
        (r,) the encoders' readings over the step, metres.
    errors
        (h, 3) each hypothesis' ``(δ_L, δ_R, δ_b)`` (:func:`sigma_errors`).
    model
        Nominal track and slip variance.

    Returns
    -------
    poses, slip_cov, distance_m, turn_rad
        After the step; and the nominal hypothesis' arc length (m) and turn (rad). Under
        errors ``δ`` and slip ``w``, ``a = (1 + δ_L)·u_L + w_L`` and ``c = (1 + δ_R)·u_R + w_R``
        are the wheels' travel, ``Δs = (a + c)/2``, ``Δθ = (c - a)/(b·(1 + δ_b))``, and the
        base moves along an arc: ``x += Δs·k·cos(yaw + Δθ/2)``, ``y += Δs·k·sin(yaw +
        Δθ/2)``, ``yaw += Δθ``, ``k = sin(Δθ/2)/(Δθ/2)``. Each hypothesis moves with ``w = 0``
        exactly; the slip (``Q = diag(slip·|a|, slip·|c|)``) is propagated linearly about
        the nominal path: ``P ← F P Fᵀ + G Q Gᵀ``.
    """
    track = model.track_m * (1.0 + errors[:, 2])  # (h,)
    a = (1.0 + errors[:, 0]) * left_m[:, None]  # (r, h)
    c = (1.0 + errors[:, 1]) * right_m[:, None]
    ds = 0.5 * (a + c)
    dth = (c - a) / track
    k, dk = _chord_factor(0.5 * dth)
    phi = poses[..., 2] + 0.5 * dth
    cos_phi, sin_phi = np.cos(phi), np.sin(phi)
    out = poses.copy()
    out[..., 0] += ds * k * cos_phi
    out[..., 1] += ds * k * sin_phi
    out[..., 2] += dth

    # The slip, linearly about the nominal hypothesis.
    r = poses.shape[0]
    s0, k0, dk0, c0, n0 = ds[:, 0], k[:, 0], dk[:, 0], cos_phi[:, 0], sin_phi[:, 0]
    b = model.track_m
    j_motion = np.zeros((r, 3, 2))  # d(x, y, yaw)/d(Δs, Δθ)
    j_motion[:, 0, 0], j_motion[:, 1, 0] = k0 * c0, k0 * n0
    j_motion[:, 0, 1] = s0 * 0.5 * (dk0 * c0 - k0 * n0)
    j_motion[:, 1, 1] = s0 * 0.5 * (dk0 * n0 + k0 * c0)
    j_motion[:, 2, 1] = 1.0
    j_noise = np.array([[0.5, 0.5], [-1.0 / b, 1.0 / b]])  # d(Δs, Δθ)/d(w_L, w_R)
    G = j_motion @ j_noise  # (r, 3, 2)
    F = np.broadcast_to(np.eye(3), (r, 3, 3)).copy()
    F[:, 0, 2], F[:, 1, 2] = -s0 * k0 * n0, s0 * k0 * c0
    q = model.slip_m * np.stack([np.abs(a[:, 0]), np.abs(c[:, 0])], axis=-1)  # (r, 2)
    P = F @ slip_cov @ np.swapaxes(F, 1, 2) + (G * q[:, None, :]) @ np.swapaxes(G, 1, 2)
    return out, P, s0, dth[:, 0]


class WheelOdometry:
    """The simulated base's odometry over ``runs`` independent runs (the stage has one).

    Parameters
    ----------
    model
        The error model.
    rng
        Draws the systematic errors (now, once) and the slip (every step).
    start_pose
        (x_m, y_m, yaw_rad): the true start pose, where odometry starts with no error.
    runs
        Number of independent vehicles simulated together (for Monte-Carlo tests).

    Attributes
    ----------
    errors
        (runs, 3) the true systematic errors ``(δ_L, δ_R, δ_b)`` of each run.
    distance_m
        (runs,) path length of the base's centre as the wheels measured it, metres.
    """

    def __init__(
        self,
        model: OdometryErrorModel,
        rng: np.random.Generator,
        start_pose: tuple[float, float, float],
        runs: int = 1,
    ) -> None:
        if runs < 1:
            raise ValueError(f"runs must be at least 1, got {runs}")
        self.model = model
        self.rng = rng
        self.errors = rng.standard_normal((runs, 3)) @ _sqrt_psd(model.prior()).T
        self._sigma_errors, self._weights = sigma_errors(model)
        self._poses = np.zeros((runs, self._weights.size, 3))
        self._poses[:] = start_pose
        self._slip_cov = np.zeros((runs, 3, 3))
        self.distance_m = np.zeros(runs)
        self._moved = np.zeros((runs, 2))
        self._true_track = model.track_m * (1.0 + self.errors[:, 2])  # (runs,) metres
        b = model.track_m
        self._j_noise = np.array([[0.5, 0.5], [-1.0 / b, 1.0 / b]])  # d(Δs, Δθ)/d(w_L, w_R)

    def advance(self, distance_m: float, turn_rad: float) -> None:
        """The base truly moved ``distance_m`` along an arc turning by ``turn_rad`` (the same
        in every run): read the encoders and integrate, in steps of at most
        :data:`MAX_STEP_M` and :data:`MAX_STEP_RAD`."""
        if distance_m == 0.0 and turn_rad == 0.0:
            return
        n = max(1, math.ceil(max(abs(distance_m) / MAX_STEP_M, abs(turn_rad) / MAX_STEP_RAD)))
        runs = self._poses.shape[0]
        left, right = wheel_travel(distance_m / n, turn_rad / n, self._true_track)
        for _ in range(n):
            normal = self.rng.standard_normal((runs, 2))
            # encoder_readings() and propagate(), the readings, the hypotheses' motion and
            # the Jacobians compiled, the products (BLAS's) as there: the same to the bit.
            self._poses, j_motion, F, q, ds, dth = move_hypotheses(
                self._poses, left, right, self.errors, normal, self._sigma_errors,
                self.model.track_m, self.model.slip_m,
            )  # fmt: skip
            G = j_motion @ self._j_noise
            self._slip_cov = F @ self._slip_cov @ np.swapaxes(F, 1, 2) + (
                G * q[:, None, :]
            ) @ np.swapaxes(G, 1, 2)
            self.distance_m += np.abs(ds)
            self._moved[:, 0] += ds
            self._moved[:, 1] += dth

    @property
    def pose(self) -> FloatArray:
        """(runs, 3) ``(x_m, y_m, yaw_rad)`` in ``odom`` (dead reckoning with the nominal
        parameters); yaw not wrapped."""
        return self._poses[:, 0].copy()

    @property
    def pose_covariance(self) -> FloatArray:
        """(runs, 3, 3) the covariance of the pose's error, about :attr:`pose`: the
        systematic errors' hypotheses' spread about the nominal path (a second moment about
        the published pose, so it also covers the bias that the nonlinear map gives the
        mean), plus the slip's share."""
        d = self._poses[:, 1:] - self._poses[:, :1]  # (runs, h - 1, 3)
        P: FloatArray = np.einsum("h,rhi,rhj->rij", self._weights[1:], d, d) + self._slip_cov
        return 0.5 * (P + np.swapaxes(P, 1, 2))

    def take_motion(self) -> FloatArray:
        """(runs, 2) estimated arc length (m) and turn (rad) since the last call."""
        moved, self._moved = self._moved, np.zeros_like(self._moved)
        return moved


def _sqrt_psd(cov: FloatArray) -> FloatArray:
    """A matrix ``L`` with ``L Lᵀ = cov`` for a positive semi-definite ``cov``."""
    values, vectors = np.linalg.eigh(cov)
    return np.asarray(vectors * np.sqrt(np.clip(values, 0.0, None)), dtype=np.float64)
