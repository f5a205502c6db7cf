"""Motion compensation (:mod:`agent.perception.filtering.placement`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.calibration.table import Calibration
from agent.kinematics.trajectory import ConstantTwist
from agent.perception.filtering import (
    PlacedPoints,
    PoseHistory,
    SampleFlag,
    place_samples,
    placement_kernels,
)
from agent.sensor.params import SensorParameters
from agent.sim.world import World
from tests.unit.perception.filtering.scans import calibrated_scan, gate_and_segment_scan


def test_motion_compensation_straightens_a_wall_seen_while_driving_and_turning(
    head: SensorParameters, calibration: Calibration
) -> None:
    """At 0.5 m/s and 1 rad/s a wall comes out straight with compensation, bent without.

    Straight: normal residuals to the true wall, in units of each point's σ along the
    normal, have RMS near 1 (tolerance 0.8-1.25 over ~250 points, where the RMS of true
    Gaussian residuals varies by ±0.05); without compensation the 100 ms of driving and
    turning bends it by centimetres: a mean squared z over 4 (χ² of ~1000 for ~250 points).
    """
    wall = World.build(walls=[(((1.6, -3.0), (1.6, 3.0)), 1.0)])
    twist = ConstantTwist(-head.mount_offset_m, 0.0, 0.0, speed_m_s=0.5, yaw_rate_rad_s=1.0)
    scan, _ = calibrated_scan(wall, head, calibration, seed=4, trajectory=twist)
    flags, _ = gate_and_segment_scan(scan, calibration)
    ok = flags == SampleFlag.VALID
    reference = float(scan.time_s[-1])
    rx, _, ryaw = (float(a[0]) for a in twist.poses_at(np.array([reference])))

    def normal_z(history: PoseHistory) -> np.ndarray:
        placed = place_samples(
            scan.time_s,
            scan.scan_angle_rad,
            scan.pan_rad,
            scan.range_m,
            scan.sigma_m,
            calibration.scan_angle_sigma_rad,
            history,
            reference,
            head.mount_offset_m,
        )
        # The wall x = 1.6 (world) in the vehicle frame at the reference time.
        c, s = math.cos(ryaw), math.sin(ryaw)
        p = placed.points_xy[ok]
        world_x = rx + c * p[:, 0] - s * p[:, 1]
        normal_world = np.array([1.0, 0.0])
        normal_vehicle = np.array(
            [c * normal_world[0] + s * normal_world[1], -s * normal_world[0] + c * normal_world[1]]
        )
        sigma_n = np.sqrt(
            np.einsum("i,nij,j->n", normal_vehicle, placed.covariance[ok], normal_vehicle)
        )
        z: np.ndarray = (world_x - 1.6) / sigma_n
        return z

    compensated = normal_z(PoseHistory.sampled(twist, reference - 0.2, reference + 0.05))
    assert ok.sum() > 200
    assert 0.8 < np.sqrt(np.mean(compensated**2)) < 1.25
    bent = normal_z(PoseHistory())  # every sample placed as if taken at the reference pose
    assert np.mean(bent**2) > 4.0


def test_pose_history_interpolates_and_extrapolates() -> None:
    h = PoseHistory()
    h.add(0.0, 0.0, 0.0, 3.1, 1.0, 0.0)
    h.add(1.0, 1.0, 0.0, -3.1, 1.0, 0.0)  # yaw wraps: the shorter way is through ±π
    x, _, yaw = h.poses_at(np.array([0.5, 2.0, -0.5]))
    assert x[0] == pytest.approx(0.5)
    assert abs(math.remainder(yaw[0] - math.pi, math.tau)) < 1e-9
    assert x[1] == pytest.approx(1.0 + math.cos(-3.1 + 2 * math.pi))  # 1 s more at 1 m/s
    assert x[2] == pytest.approx(-0.5 * math.cos(3.1))  # before the first: its motion, backwards
    h.add(0.5, 9.0, 9.0, 0.0, 0.0, 0.0)  # out of order: dropped, counted
    h.add(1.0, 7.0, 7.0, 0.0, 0.0, 0.0)  # the newest stamp again: dropped, counted
    assert len(h) == 2 and (h.out_of_order, h.duplicates) == (1, 1)
    assert h.poses_at(np.array([1.0]))[0][0] == pytest.approx(1.0)  # the first kept


def _reference_poses_and_age(
    states: np.ndarray, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``placement_kernels.poses_and_age`` in numpy: interpolation, the end states' arcs and
    the time to the newest state at or before each time (before the first: to the first)."""
    ts, xs, ys, yaws, v, w = states.T
    x, y, yaw = np.interp(t, ts, xs), np.interp(t, ts, ys), np.interp(t, ts, yaws)
    for end, outside in ((-1, t > ts[-1]), (0, t < ts[0])):
        dt = t[outside] - ts[end]
        yaw[outside] = yaws[end] + w[end] * dt
        x[outside] = xs[end] + v[end] / w[end] * (np.sin(yaw[outside]) - np.sin(yaws[end]))
        y[outside] = ys[end] - v[end] / w[end] * (np.cos(yaw[outside]) - np.cos(yaws[end]))
    behind = np.searchsorted(ts, t, side="right") - 1
    age = np.where(behind >= 0, t - ts[np.maximum(behind, 0)], ts[0] - t)
    return x, y, yaw, float(age.max())


def test_pose_look_up_kernel_matches_numpy(rng: np.random.Generator) -> None:
    """Interpolation, the arcs past either end and the state age, against numpy."""
    stamps = np.cumsum(rng.uniform(0.005, 0.05, 40))
    states = np.column_stack(
        [
            stamps,
            *rng.normal(0.0, 1.0, (3, 40)),
            rng.uniform(-0.5, 0.5, 40),
            rng.uniform(0.2, 1, 40),
        ]
    )
    t = rng.uniform(stamps[0] - 0.2, stamps[-1] + 0.3, 500)
    t[:3] = stamps[0], stamps[-1], stamps[7]  # on states: exact
    got = placement_kernels.poses_and_age(states, t)
    want = _reference_poses_and_age(states, t)
    for g, w in zip(got[:3], want[:3], strict=True):
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-12)
    assert got[3] == pytest.approx(want[3], abs=1e-15)
    np.testing.assert_array_equal(got[0][:3], states[[0, -1, 7], 1])
    straight = states.copy()
    straight[:, 5] = 0.0  # no turning: straight lines past the ends
    x, y, _, _ = placement_kernels.poses_and_age(straight, np.array([stamps[-1] + 0.5]))
    heading = states[-1, 3]
    assert x[0] == pytest.approx(states[-1, 1] + 0.5 * states[-1, 4] * math.cos(heading))
    assert y[0] == pytest.approx(states[-1, 2] + 0.5 * states[-1, 4] * math.sin(heading))


def test_pose_history_keeps_its_seconds_and_unwraps_yaw_as_states_arrive() -> None:
    """Spinning at 5 rad/s for 10 s at 50 Hz: 3 s kept, yaw continuous (as numpy.unwrap)."""
    h = PoseHistory(seconds=3.0)
    times = (np.arange(500) * 0.02).astype(np.float64)
    wrapped = np.remainder(5.0 * times + math.pi, math.tau) - math.pi
    for t, yaw in zip(times, wrapped, strict=True):
        h.add(float(t), math.cos(t), math.sin(t), float(yaw), 0.0, 5.0)
    assert len(h) == 151  # 9.98 - 3.0 ... 9.98
    x, _, yaw = h.poses_at(times[-151:])
    np.testing.assert_allclose(x, np.cos(times[-151:]), atol=1e-12)
    np.testing.assert_allclose(np.diff(yaw), 0.1, atol=1e-9)
    assert h.state_age_s(np.array([times[-151] - 0.05, 10.0])) == pytest.approx(0.05)


def _placed(history: PoseHistory, max_state_age_s: float) -> PlacedPoints:
    """A 0.1 s sweep of a wall 1 m ahead, ending at t = 1.25 s."""
    n = 256
    return place_samples(
        np.linspace(1.15, 1.25, n),
        np.linspace(-0.3, 0.3, n),
        np.zeros(n),
        np.full(n, 1.0),
        np.full(n, 1e-3),
        1e-4,
        history,
        1.25,
        0.3,
        max_state_age_s,
    )


def _driving(until_s: float) -> PoseHistory:
    """States at 50 Hz up to ``until_s``, driving at 0.5 m/s and turning at 1 rad/s."""
    twist = ConstantTwist(0.0, 0.0, 0.0, speed_m_s=0.5, yaw_rate_rad_s=1.0)
    return PoseHistory.sampled(twist, 0.0, until_s + 1e-9)


def test_stale_vehicle_state_turns_compensation_off_at_the_limit() -> None:
    """The newest state at 1.0 s, the scan ending at 1.25 s: a state age of 0.25 s, exactly.

    Up to 0.25 s the scan is compensated; past it every sample is placed with the
    reference pose (as with no state at all) and the result says so.
    """
    history = _driving(until_s=1.0)
    fresh = _placed(history, max_state_age_s=0.25)
    assert fresh.motion_compensated and fresh.state_age_s == 0.25
    stale = _placed(history, max_state_age_s=0.2499)
    assert not stale.motion_compensated and stale.state_age_s == 0.25
    still = _placed(PoseHistory(), max_state_age_s=0.2499)
    assert not still.motion_compensated and still.state_age_s == math.inf
    np.testing.assert_array_equal(stale.points_xy, still.points_xy)
    np.testing.assert_array_equal(stale.covariance, still.covariance)
    # Compensation moves points by centimetres here: the flag tells two different results.
    assert np.abs(fresh.points_xy - stale.points_xy).max() > 0.02


def test_a_gap_in_the_vehicle_states_counts_as_stale() -> None:
    """States up to 1.0 s and again from 1.5 s: samples at 1.15-1.25 s are interpolated
    across the gap, their state age up to 0.25 s past the state before it."""
    history = _driving(until_s=1.0)
    history.add(1.5, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert _placed(history, max_state_age_s=0.25).motion_compensated
    assert not _placed(history, max_state_age_s=0.2).motion_compensated


def test_a_scan_before_the_first_state_is_aged_to_it() -> None:
    """States from 1.5 s on: the scan ending at 1.25 s is 0.35 s before the first."""
    history = PoseHistory()
    history.add(1.5, 0.0, 0.0, 0.0, 0.5, 0.0)
    placed = _placed(history, max_state_age_s=0.3)
    assert not placed.motion_compensated and placed.state_age_s == pytest.approx(0.35)
    assert _placed(history, max_state_age_s=0.35 + 1e-9).motion_compensated
