"""Wheel odometry: exact without errors, drift of the stated size, an honest covariance."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import stats

from agent.sim.odometry import (
    MAX_STEP_M,
    MAX_STEP_RAD,
    OdometryErrorModel,
    WheelOdometry,
    encoder_readings,
    propagate,
    wheel_travel,
)

START = (1.0, 2.0, 0.3)
SPEED = 0.4
DT_S = 0.05  # the world stage's 20 Hz
# A scripted drive (speed m/s, yaw rate rad/s, duration s): a straight, a left arc of 1 m
# radius, a straight, a right turn on the spot, a straight, a right arc of 1.5 m radius:
# exactly 10 m of path; then a gentle left arc for 5 m more.
SCRIPT = [
    (SPEED, 0.0, 3.0 / SPEED),
    (SPEED, SPEED / 1.0, (math.pi / 2) / (SPEED / 1.0)),
    (SPEED, 0.0, 2.0 / SPEED),
    (0.0, -0.8, (math.pi / 2) / 0.8),
    (SPEED, 0.0, (10.0 - 3.0 - math.pi / 2 - 2.0 - 1.5 * math.pi / 2) / SPEED),
    (SPEED, -SPEED / 1.5, (math.pi / 2) / (SPEED / 1.5)),
]
EXTRA = [(SPEED, SPEED / 4.0, 5.0 / SPEED)]
SEED = 0


def drive(
    odometry: WheelOdometry, script: list[tuple[float, float, float]], pose: list[float]
) -> list[float]:
    """Drive ``script`` in 20 Hz steps, moving the true ``pose`` (exact arcs) and the
    odometry alike; return the true pose."""
    x, y, yaw = pose
    for speed, yaw_rate, duration in script:
        n = round(duration / DT_S)
        h = duration / n
        for _ in range(n):
            ds, dth = speed * h, yaw_rate * h
            k = 1.0 if dth == 0.0 else math.sin(dth / 2) / (dth / 2)
            x += ds * k * math.cos(yaw + dth / 2)
            y += ds * k * math.sin(yaw + dth / 2)
            yaw += dth
            odometry.advance(ds, dth)
    return [x, y, yaw]


def errors(odometry: WheelOdometry, truth: list[float]) -> np.ndarray:
    e = np.asarray(truth) - odometry.pose
    e[:, 2] = np.remainder(e[:, 2] + math.pi, 2 * math.pi) - math.pi
    return e


def nees(odometry: WheelOdometry, truth: list[float]) -> np.ndarray:
    e = errors(odometry, truth)
    return np.asarray(np.einsum("ri,rij,rj->r", e, np.linalg.inv(odometry.pose_covariance), e))


def test_without_errors_odometry_is_the_truth() -> None:
    model = OdometryErrorModel(scale_sigma=0.0, ratio_sigma=0.0, track_sigma=0.0, slip_m=0.0)
    odometry = WheelOdometry(model, np.random.default_rng(0), START)
    truth = drive(odometry, SCRIPT + EXTRA, list(START))
    np.testing.assert_allclose(odometry.pose[0], truth, atol=1e-9)
    np.testing.assert_allclose(odometry.pose_covariance[0], 0.0, atol=1e-15)
    assert odometry.distance_m[0] == pytest.approx(15.0, abs=1e-9)


def test_odometry_starts_at_the_start_pose_with_no_uncertainty() -> None:
    odometry = WheelOdometry(OdometryErrorModel(), np.random.default_rng(0), START)
    np.testing.assert_array_equal(odometry.pose[0], START)
    np.testing.assert_array_equal(odometry.pose_covariance[0], np.zeros((3, 3)))
    odometry.advance(0.0, 0.0)  # standing still: nothing drawn, nothing grows
    np.testing.assert_array_equal(odometry.pose_covariance[0], np.zeros((3, 3)))


def test_the_covariance_is_honest_nees_over_200_runs_at_10_m() -> None:
    # 200 seeded runs of the scripted drive with turns. The pose error's NEES is chi-square
    # with 3 degrees of freedom if the covariance is honest, so 200 times its mean is
    # chi-square with 600: the mean must lie inside that two-sided 95 % interval,
    # [2.67, 3.35]. (A linearised EKF over the same augmented state gave 4.7: see
    # agent.sim.odometry.) Seed fixed. The error is not Gaussian (a banana), so the NEES's
    # tail is heavier than chi-square's: over seeds 0-19 the mean is 3.02 but 3 of the 20
    # fall outside this interval (at 15 m, 2.98 and 7 of 20).
    runs = 200
    odometry = WheelOdometry(OdometryErrorModel(), np.random.default_rng(SEED), START, runs=runs)
    truth = drive(odometry, SCRIPT, list(START))
    assert float(np.mean(odometry.distance_m)) == pytest.approx(10.0, rel=0.02)
    lo, hi = (stats.chi2.ppf(q, 3 * runs) / runs for q in (0.025, 0.975))
    assert lo <= float(np.mean(nees(odometry, truth))) <= hi


def test_the_covariance_grows_with_distance_and_turning() -> None:
    odometry = WheelOdometry(OdometryErrorModel(), np.random.default_rng(4), START)
    position_variance = []
    pose = list(START)
    for leg in SCRIPT:
        pose = drive(odometry, [leg], pose)
        position_variance.append(float(np.trace(odometry.pose_covariance[0, :2, :2])))
    # Position variance grows on every leg that moves the base (not on the turn on the
    # spot, leg 4, where it may shrink as well as grow: the heading's variance can fall when
    # a turn undoes an earlier one's track error).
    grows = [b > a for a, b in itertools.pairwise(position_variance)]
    assert grows[0] and grows[1] and grows[3] and grows[4]
    # A turn on the spot from the start: the heading's variance grows (track error, slip)
    # and the position's barely (the ratio error moves the centre ratio_sigma·b·π/4 = 6 mm).
    spin = WheelOdometry(OdometryErrorModel(), np.random.default_rng(4), START)
    spin.advance(0.0, math.pi)
    P = spin.pose_covariance[0]
    # Each wheel rolls ±b·π/2: the common scale error (both read short or long) and the
    # track error each scale the turn: σ = π·hypot(track_sigma, scale_sigma), slip aside.
    assert math.sqrt(P[2, 2]) == pytest.approx(math.pi * math.hypot(0.02, 0.015), rel=0.05)
    assert math.sqrt(np.trace(P[:2, :2])) < 0.01


def test_drift_is_about_the_stated_size() -> None:
    # 10 m straight ahead, 1000 seeded runs. The defaults give an RMS distance error of
    # sqrt(scale_sigma² + slip_m/(2·10 m)) = 1.5 % and an RMS heading drift of
    # ratio_sigma / track_m = 1.72 °/m (plus slip, 0.16 °/m): inside the 1-2 % and 1-3 °/m
    # asked for. Tolerance ±10 %: an RMS over 1000 Gaussian runs has a relative standard
    # error of 1/sqrt(2000) = 2.2 %, so this is 4.5 standard errors.
    runs, length = 1000, 10.0
    model = OdometryErrorModel()
    odometry = WheelOdometry(model, np.random.default_rng(21), (0.0, 0.0, 0.0), runs=runs)
    odometry.advance(length, 0.0)
    distance_error = np.abs(odometry.distance_m - length) / length
    heading_deg_per_m = np.degrees(odometry.pose[:, 2]) / length
    rms_distance = float(np.sqrt(np.mean(distance_error**2)))
    rms_heading = float(np.sqrt(np.mean(heading_deg_per_m**2)))
    expected_distance = math.sqrt(model.scale_sigma**2 + model.slip_m / (2 * length))
    slip_heading = math.sqrt(2 * model.slip_m * length) / model.track_m
    expected_heading = math.degrees(
        math.hypot(model.ratio_sigma / model.track_m * length, slip_heading) / length
    )
    assert rms_distance == pytest.approx(expected_distance, rel=0.1)
    assert rms_heading == pytest.approx(expected_heading, rel=0.1)
    assert 0.01 <= rms_distance <= 0.02 and 1.0 <= rms_heading <= 3.0


def test_same_seed_same_odometry_and_runs_differ() -> None:
    poses = []
    for seed in (3, 3, 4):
        odometry = WheelOdometry(OdometryErrorModel(), np.random.default_rng(seed), START, 2)
        drive(odometry, SCRIPT[:2], list(START))
        poses.append(odometry.pose)
    np.testing.assert_array_equal(poses[0], poses[1])
    assert not np.array_equal(poses[0], poses[2])
    assert not np.array_equal(poses[0][0], poses[0][1])


def test_the_compiled_step_equals_propagate_to_the_bit() -> None:
    """WheelOdometry's step (agent.sim.odometry_kernels, with numpy's matrix products)
    against propagate(), its numpy formulation, step for step over the scripted drive,
    forwards and backwards, with four runs at once: poses, covariances and distances equal."""
    model = OdometryErrorModel()
    odometry = WheelOdometry(model, np.random.default_rng(SEED), START, runs=4)
    replay = np.random.default_rng(SEED)
    errors = replay.standard_normal((4, 3))  # drawn as the odometry drew its own
    assert odometry.errors.shape == errors.shape
    hyp = odometry._poses.copy()
    slip = odometry._slip_cov.copy()
    distance = np.zeros(4)
    for speed, yaw_rate, duration in [*SCRIPT, (-SPEED, 0.3, 2.0), (0.0, 0.0, 0.5)]:
        n = round(duration / DT_S)
        for _ in range(n):
            h = duration / n
            odometry.advance(speed * h, yaw_rate * h)
            if speed * h == 0.0 and yaw_rate * h == 0.0:
                continue
            steps = max(
                1, math.ceil(max(abs(speed * h) / MAX_STEP_M, abs(yaw_rate * h) / MAX_STEP_RAD))
            )
            track = model.track_m * (1.0 + odometry.errors[:, 2])
            left, right = wheel_travel(speed * h / steps, yaw_rate * h / steps, track)
            for _ in range(steps):
                normal = replay.standard_normal((4, 2))
                u_left, u_right = encoder_readings(left, right, odometry.errors, model.slip_m,
                                                   normal)  # fmt: skip
                hyp, slip, ds, _ = propagate(hyp, slip, u_left, u_right,
                                             odometry._sigma_errors, model)  # fmt: skip
                distance += np.abs(ds)
    np.testing.assert_array_equal(odometry._poses, hyp)
    np.testing.assert_array_equal(odometry._slip_cov, slip)
    np.testing.assert_array_equal(odometry.distance_m, distance)


def test_wheel_travel() -> None:
    left, right = wheel_travel(1.0, 0.4, 0.5)
    assert (float(left), float(right)) == pytest.approx((0.9, 1.1))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"track_m": 0.0}, "track_m"),
        ({"scale_sigma": -0.1}, "scale_sigma"),
        ({"ratio_sigma": math.nan}, "ratio_sigma"),
        ({"track_sigma": 0.6}, "track_sigma"),
        ({"slip_m": -1.0}, "slip_m"),
    ],
)
def test_model_refuses_bad_values(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        OdometryErrorModel(**kwargs)
    with pytest.raises(ValueError, match="runs"):
        WheelOdometry(OdometryErrorModel(), np.random.default_rng(0), START, runs=0)
