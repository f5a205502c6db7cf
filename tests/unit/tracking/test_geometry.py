"""Transforms into ``odom``, the drift process noise, the pose history and visibility."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.tracking.geometry import (
    lines_to_odom,
    point_drift_jacobian,
    point_drift_noise,
    points_to_base,
    points_to_odom,
    pose_noise_increment,
)
from agent.tracking.poses import PoseCovarianceHistory
from agent.tracking.visibility import point_visibility, scan_beams, segment_ends_seen
from tests.unit.tracking.scenes import Odometry, Scene, cast


def test_lines_follow_their_points_into_odom() -> None:
    pose = np.array([1.0, -2.0, 0.7])
    alpha, rho = np.array([0.3, -2.0]), np.array([1.2, 0.8])
    cov = np.tile(np.diag([1e-4, 4e-4]), (2, 1, 1))
    a, r, _ = lines_to_odom(pose, alpha, rho, cov)
    for k in range(2):
        n = np.array([math.cos(alpha[k]), math.sin(alpha[k])])
        pts = rho[k] * n + np.outer([-1.0, 2.0], [-n[1], n[0]])  # two points on the line
        po = points_to_odom(pose, pts)
        assert np.allclose(po @ [math.cos(a[k]), math.sin(a[k])], r[k])
        assert np.allclose(points_to_base(pose, po), pts)


def test_line_covariance_matches_a_numerical_jacobian() -> None:
    pose = np.array([3.0, 1.0, -0.4])
    alpha, rho = np.array([0.5]), np.array([1.5])
    cov = np.array([[[2e-4, 1e-5], [1e-5, 3e-4]]])
    _, _, got = lines_to_odom(pose, alpha, rho, cov)
    eps = 1e-6
    J = np.zeros((2, 2))
    base = np.array(lines_to_odom(pose, alpha, rho, cov)[:2])[:, 0]
    for j in range(2):
        d = np.zeros(2)
        d[j] = eps
        moved = np.array(lines_to_odom(pose, alpha + d[0], rho + d[1], cov)[:2])[:, 0]
        J[:, j] = (moved - base) / eps
    assert np.allclose(got[0], J @ cov[0] @ J.T, rtol=1e-5)


def test_drift_noise_is_the_new_error_only() -> None:
    # A covariance only carried along the path (no new error) moves no static feature.
    cov = np.diag([1e-3, 2e-3, 1e-3])
    dx, dy = 0.4, 0.1
    F = np.array([[1, 0, -dy], [0, 1, dx], [0, 0, 1.0]])
    assert np.allclose(pose_noise_increment(cov, F @ cov @ F.T, dx, dy), 0.0, atol=1e-15)
    # New error N is returned as it is; a shrinking covariance adds nothing.
    N = np.diag([1e-4, 1e-4, 3e-5])
    assert np.allclose(pose_noise_increment(cov, F @ cov @ F.T + N, dx, dy), N)
    assert np.allclose(pose_noise_increment(cov, 0.5 * cov, 0.0, 0.0), 0.0)
    # Q = J·ΔΣ·Jᵀ written out equals the product.
    pts = np.array([[2.0, 1.0], [-1.0, 3.0]])
    v = np.array([0.5, -0.2])
    J = point_drift_jacobian(pts, v)
    assert np.allclose(point_drift_noise(pts, v, N), J @ N @ J.transpose(0, 2, 1))


@pytest.mark.slow
def test_drift_moves_a_static_feature_as_the_noise_model_says(rng: np.random.Generator) -> None:
    # Monte Carlo over the test odometry: the feature's odom position after a drive has
    # the covariance the summed J·ΔΣ·Jᵀ predicts (1000 runs: a variance estimate then has a
    # relative σ of 4.5 %; tolerance 15 %, over 3σ).
    feature = np.array([[3.0, 1.0]])
    steps = [np.array([0.05 * k, 0.01 * k * k / 10, 0.02 * k]) for k in range(40)]
    finals = []
    Q = np.zeros((2, 2))
    for run in range(1000):
        odo = Odometry(np.random.default_rng(run))
        prev = None
        for p in steps:
            odo.step(p)
            if run == 0 and prev is not None:
                d = odo.pose[:2] - prev[0][:2]
                dS = pose_noise_increment(prev[1], odo.cov, float(d[0]), float(d[1]))
                Q += point_drift_noise(odo.to_odom(feature), odo.pose[:2], dS)[0]
            prev = (odo.pose.copy(), odo.cov.copy())
        finals.append(odo.to_odom(feature)[0])
    emp = np.cov(np.array(finals).T)
    assert np.allclose(np.diag(emp), np.diag(Q), rtol=0.15)


def test_pose_history_interpolates_and_reports_age() -> None:
    h = PoseCovarianceHistory()
    assert h.at(1.0) is None
    h.add(1.0, np.array([0.0, 0.0, 3.1]), np.eye(3) * 1e-4, 1.0, 0.0)
    h.add(1.1, np.array([0.1, 0.0, -3.1]), np.eye(3) * 3e-4, 1.0, 0.0)  # across ±π
    got = h.at(1.05)
    assert got is not None
    assert np.allclose(got.pose[:2], [0.05, 0.0]) and abs(got.pose[2] - math.pi) < 1e-9
    assert np.allclose(got.covariance, np.eye(3) * 2e-4) and math.isclose(got.age_s, 0.05)
    ahead = h.at(1.3)  # extrapolated along the heading, age from the newest state
    assert ahead is not None and math.isclose(ahead.age_s, 0.2)
    h.add(1.1, np.zeros(3), np.eye(3), 0.0, 0.0)
    h.add(0.5, np.zeros(3), np.eye(3), 0.0, 0.0)
    assert (h.duplicates, h.out_of_order) == (1, 1)


def test_visibility_in_view_out_of_view_and_occluded() -> None:
    # A 0.3 m pillar at 1.2 m straight ahead hides what is behind it.
    scene = Scene(pillars=np.array([[1.5, 0.0, 0.3]]), walls=np.array([[[2.6, -3], [2.6, 3.0]]]))
    scan, _ = cast(np.zeros(3), scene, 0.0, math.radians(10), (-0.35, 0.35))
    beams = scan_beams(scan.points_xy, scan.origin_xy, scan.scan_angle_rad, scan.range_m,
                       scan.flag, 0.4, 2.5)  # fmt: skip
    assert beams is not None
    assert np.allclose(beams.heading_rad, math.radians(10) + scan.scan_angle_rad)
    pts = np.array([[2.2, 0.0], [1.8, 0.6], [2.2, -2.0], [1.5, 0.0]])
    view = point_visibility(
        beams, pts, np.array([0.0, 0.0, 0.0, 0.3]), np.array([0.05, 0.05, 0.05, 0.3]),
        np.full(4, 0.01), np.full(4, 3), np.zeros(4, dtype=bool), 0.4, 2.5,
    )  # fmt: skip
    # Behind the pillar: occluded; to the left, in the window and clear: visible; far right,
    # out of the window: neither; the pillar itself: visible.
    assert view.visible.tolist() == [False, True, False, True]
    assert view.occluded.tolist() == [True, False, False, False]


def test_segment_ends_seen_only_where_the_surface_stops() -> None:
    # A wall from y = -0.3 to 0.3 at x = 1.5 with the far wall behind: both ends seen. The
    # same wall past the window's edges: neither.
    wall = np.array([[1.5, -0.3], [1.5, 0.3]])
    back = np.array([[2.3, -3.0], [2.3, 3.0]])
    for window, expected in (((-0.35, 0.35), [True, True]), ((-0.1, 0.1), [False, False])):
        scene = Scene(walls=np.array([wall, back]))
        scan, hits = cast(np.zeros(3), scene, 0.0, 0.0, window)
        on = np.flatnonzero(hits == 0)
        ends = scan.points_xy[[on[0], on[-1]]][None]
        got = segment_ends_seen(ends, np.zeros(1), np.full(1, 1.5), scan.points_xy,
                                scan.origin_xy, scan.range_m, scan.flag, 2.5)  # fmt: skip
        assert got[0].tolist() == expected
