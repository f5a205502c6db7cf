"""Obstacles from tracks (confirmed only, docking targets) and the sensor's health."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from agent.planning.environment import (
    DOCKING,
    DOCKING_REFLECTIVITY,
    HeadReport,
    across_sigma,
    obstacles_from_tracks,
    sensor_health,
)


def _tracks(kind: list[int], status: list[int], refl: list[float]) -> dict[str, np.ndarray]:
    k = len(kind)
    state = np.arange(4 * k, dtype=np.float64).reshape(k, 4)
    extent = np.zeros((k, 4))
    extent[:, :] = [[0.0, 1.0, 2.0, 3.0]]
    return {
        "track_id": np.arange(10, 10 + k, dtype=np.int64),
        "kind": np.array(kind, dtype=np.uint8),
        "status": np.array(status, dtype=np.uint8),
        "state": state,
        "covariance": np.tile(np.eye(4), (k, 1, 1)),
        "extent": extent,
        "reflectivity": np.array(refl, dtype=np.float64),
    }


def test_only_confirmed_and_coasting_tracks_are_obstacles() -> None:
    obstacles, counts = obstacles_from_tracks(**_tracks([0, 1, 3, 3], [0, 1, 2, 0], [1] * 4))
    assert obstacles.obstacle_id.tolist() == [11, 12]
    assert obstacles.kind.tolist() == [1, 3]
    assert counts.tentative == 2
    np.testing.assert_array_equal(obstacles.position_xy, [[4, 5], [8, 9]])
    np.testing.assert_array_equal(obstacles.velocity_xy, [[6, 7], [10, 11]])
    # A corner has no extent; a cylinder keeps its (r, 0, 0, 0) as tracked.
    np.testing.assert_array_equal(obstacles.extent[0], 0.0)
    np.testing.assert_array_equal(obstacles.extent[1], [0, 1, 2, 3])


def test_a_bright_segment_is_a_docking_target() -> None:
    t = DOCKING_REFLECTIVITY
    tracks = _tracks([0, 0, 0, 3], [1, 1, 1, 1], [2.0, t, np.nan, 5.0])
    obstacles, counts = obstacles_from_tracks(**tracks)
    # Walls are up to 2.0; a cylinder is never a docking target; NaN is not bright.
    assert obstacles.kind.tolist() == [0, DOCKING, 0, 3]
    assert counts.docking == 1
    np.testing.assert_array_equal(obstacles.extent[1], [0, 1, 2, 3])  # its end points
    assert np.isnan(obstacles.reflectivity[2])
    obstacles, _ = obstacles_from_tracks(**tracks, docking_reflectivity=6.0)
    assert DOCKING not in obstacles.kind.tolist()


def test_non_finite_tracks_are_dropped_and_counted() -> None:
    tracks = _tracks([3, 3], [1, 1], [1.0, 1.0])
    tracks["covariance"][0, 0, 0] = np.inf
    obstacles, counts = obstacles_from_tracks(**tracks)
    assert obstacles.obstacle_id.tolist() == [11]
    assert counts.non_finite == 1


def _head(mode: str = "scanning", laser: bool = True, accepted: bool = True) -> HeadReport:
    return HeadReport(stamp_s=10.0, mode=mode, laser_on=laser, command_accepted=accepted)


def test_fresh_inputs_and_a_scanning_head_are_healthy() -> None:
    assert sensor_health(10.1, 0.3, 10.1, 10.05, 10.08, _head()) == []


def test_stale_inputs_are_named() -> None:
    assert sensor_health(10.5, 0.3, 10.1, 10.4, 10.4, _head()) == ["stale_tracks", "stale_head"]
    assert sensor_health(10.0, 0.3, None, None, None, None) == [
        "stale_tracks", "stale_scans", "stale_vehicle", "stale_head",
    ]  # fmt: skip


def test_head_faults_are_named() -> None:
    ok = (10.0, 0.3, 10.0, 10.0, 10.0)
    assert sensor_health(*ok, _head(mode="fault", laser=False)) == ["head_fault"]
    assert sensor_health(*ok, _head(mode="idle", laser=False)) == ["laser_off"]
    assert sensor_health(*ok, _head(mode="idle", laser=False, accepted=False)) == [
        "laser_off", "command_refused",
    ]  # fmt: skip


def test_a_segments_across_line_sigma_is_its_lines_at_the_worse_end() -> None:
    """The line y = 1 (α = π/2, ρ = 1) from x = −0.2 to x = 0.6: σ_ρ 2 mm, σ_α 10 mrad,
    uncorrelated. At an end point s = p · (−sin α, cos α) = −x, so σ_n² = σ_ρ² + x²·σ_α²,
    the larger at x = 0.6: √(4e-6 + 3.6e-5) = 6.3 mm; a correlation P_αρ enters as
    −2·s·P_αρ; other kinds 0; non-finite line parameters give the point's larger σ."""
    kind = np.array([0, 4, 3, 0], dtype=np.uint8)
    extent = np.array([[-0.2, 1.0, 0.6, 1.0]] * 2 + [[0.2, 0, 0, 0], [-0.2, 1.0, 0.6, 1.0]])
    params = np.tile([np.pi / 2, 1.0, np.nan], (4, 1))
    params[3, 0] = np.nan
    pc = np.tile(np.diag([1e-4, 4e-6, np.nan]), (4, 1, 1))
    pc[1, 0, 1] = pc[1, 1, 0] = 1e-5  # docking target: correlated
    position = np.tile(np.diag([0.05, 4e-6]), (4, 1, 1))
    got = across_sigma(kind, extent, params, pc, position)
    assert got[0] == pytest.approx(np.sqrt(4e-6 + 0.36e-4), rel=1e-9)
    # s = −x: at x = 0.6, 4e-6 + 1.2e-5 + 3.6e-5; at x = −0.2, 4e-6 − 4e-6 + 4e-6.
    assert got[1] == pytest.approx(np.sqrt(4e-6 + 1.2e-5 + 3.6e-5), rel=1e-9)
    assert got[2] == 0.0
    assert got[3] == pytest.approx(np.sqrt(0.05), rel=1e-9)
    huge = across_sigma(kind, extent, params, pc * 1e12, position * 1e12)
    assert np.all(huge[[0, 1, 3]] == 100.0)  # environment/1's range
    with warnings.catch_warnings():  # a malformed message's absurd ends: no overflow warning
        warnings.simplefilter("error")
        absurd = across_sigma(kind, extent * 1e300, params, pc, position * 1e300)
    assert np.all(absurd[[0, 1, 3]] == 100.0)


def test_obstacles_carry_the_across_line_sigma_only_when_given_the_line_parameters() -> None:
    t = _tracks([0, 3], [1, 1], [1.0, 1.0])
    plain, _ = obstacles_from_tracks(**t)
    assert plain.across_sigma_m.shape == (0,)
    params = np.array([[0.0, 1.0, np.nan], [1.0, 2.0, 0.2]])
    pc = np.tile(np.diag([1e-6, 1e-6, 1e-6]), (2, 1, 1))
    given, _ = obstacles_from_tracks(**t, params=params, params_covariance=pc)
    assert given.across_sigma_m.shape == (2,) and given.across_sigma_m[1] == 0.0
    assert 0.0 < given.across_sigma_m[0] < 0.01
