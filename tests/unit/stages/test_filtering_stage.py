"""The filtering stage over the filter's steps: gates, segmentation, compensation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agent.calibration.table import Calibration
from agent.errors import ConfigError
from agent.runtime import topics
from agent.runtime.messages import CalibratedScan, FilteredScan, Header, VehicleState
from agent.runtime.stage import Params
from agent.sensor.params import SensorParameters
from agent.sim.world import World
from agent.stages.filtering_stage import MAX_STATE_AGE_S, FilteringStage
from tests.unit.perception.filtering.scans import calibrated_scan


def _wall_scan(head: SensorParameters, calibration: Calibration) -> CalibratedScan:
    """A calibrated sweep of a wall 1.5 m ahead, standing still; samples at -0.0001-0.0995 s."""
    world = World.build(walls=[(((1.5, -2.0), (1.5, 2.0)), 1.0)])
    scan, _ = calibrated_scan(world, head, calibration)
    return CalibratedScan(
        header=Header(stamp_ns=1),
        time_s=scan.time_s,
        scan_angle_rad=scan.scan_angle_rad,
        pan_rad=scan.pan_rad,
        image_position_norm=scan.image_position_norm,
        intensity_A=scan.intensity_A,
        range_m=scan.range_m,
        sigma_m=scan.sigma_m,
        direction=scan.direction,
        sweep_index=3,
    )


def _state(stamp_s: float, x_m: float = 0.0, speed_m_s: float = 0.0) -> VehicleState:
    return VehicleState(
        header=Header(stamp_ns=round(stamp_s * 1e9)),
        x_m=x_m,
        y_m=0.0,
        yaw_rad=0.0,
        speed_m_s=speed_m_s,
        yaw_rate_rad_s=0.0,
        pose_covariance=np.eye(3) * 1e-4,
        intent_xy=np.zeros((0, 2)),
    )


def _filter(stage: FilteringStage, msg: CalibratedScan) -> FilteredScan:
    [(topic, out)] = stage.handle(topics.CALIBRATED_SCAN, msg, 0.0)
    assert topic == topics.FILTERED_SCAN and isinstance(out, FilteredScan)
    return out


def test_stage_filters_and_compensates(head: SensorParameters, calibration: Calibration) -> None:
    msg = _wall_scan(head, calibration)
    stage = FilteringStage(calibration.noise_current_A)
    out = _filter(stage, msg)
    assert not out.motion_compensated and out.sweep_index == 3
    assert np.all(out.flag == 0) and np.all(out.segment == 0)
    # Points: the wall at 1.5 m ahead of the centre of scanning, in the vehicle frame.
    assert np.allclose(out.points_xy[:, 0], 1.5 + head.mount_offset_m, atol=0.06)  # 5σ
    assert stage.handle(topics.VEHICLE_STATE, _state(0.0), 0.0) == []
    again = _filter(stage, msg)
    assert again.motion_compensated
    counters = stage.counters()
    assert counters["scans"] == 2 and counters["samples_valid"] == 512
    assert counters["uncompensated"] == counters["uncompensated_no_vehicle_state"] == 1
    assert counters["uncompensated_stale_pose"] == 0


def test_stale_vehicle_state_leaves_the_scan_uncompensated_and_counted(
    head: SensorParameters, calibration: Calibration
) -> None:
    """The scan's samples run to 10.0995 s. A state at 9.5 s, driving at 0.5 m/s, is 0.6 s
    old by then: not extrapolated, the points come out as with no state at all. A state at
    9.95 s (0.15 s old) compensates again."""
    scan = _wall_scan(head, calibration)
    msg = dataclasses.replace(scan, time_s=scan.time_s + 10.0)
    stage = FilteringStage(calibration.noise_current_A)
    stage.handle(topics.VEHICLE_STATE, _state(9.5, x_m=4.75, speed_m_s=0.5), 0.0)
    stale = _filter(stage, msg)
    assert not stale.motion_compensated
    assert stage.counters()["uncompensated_stale_pose"] == stage.counters()["uncompensated"] == 1
    assert stage.counters()["uncompensated_no_vehicle_state"] == 0
    still = _filter(FilteringStage(calibration.noise_current_A), msg)
    np.testing.assert_array_equal(stale.points_xy, still.points_xy)
    stage.handle(topics.VEHICLE_STATE, _state(9.95, x_m=4.975, speed_m_s=0.5), 0.0)
    fresh = _filter(stage, msg)
    assert fresh.motion_compensated
    assert stage.counters()["uncompensated_stale_pose"] == 1 and stage.counters()["scans"] == 2
    # Compensated, the first sample is placed from where the vehicle was 0.1 s before the
    # reference, 5 cm back at 0.5 m/s: the flag tells two different results apart.
    assert fresh.points_xy[0, 0] - still.points_xy[0, 0] == pytest.approx(-0.05, abs=1e-3)


def test_out_of_order_and_duplicate_vehicle_states_are_dropped_and_counted(
    calibration: Calibration,
) -> None:
    stage = FilteringStage(calibration.noise_current_A)
    for stamp_s, x_m in ((10.0, 1.0), (9.9, 2.0), (10.0, 3.0), (10.02, 4.0)):
        assert stage.handle(topics.VEHICLE_STATE, _state(stamp_s, x_m), 0.0) == []
    counters = stage.counters()
    assert counters["vehicle_state_out_of_order"] == counters["vehicle_state_duplicate"] == 1
    assert len(stage.poses) == 2
    x, _, _ = stage.poses.poses_at(np.array([9.9, 10.0]))
    np.testing.assert_array_equal(x, [1.0, 1.0])  # the first 10.0 s state kept, none inserted


def test_max_state_age_is_a_launch_parameter(calibration: Calibration) -> None:
    assert FilteringStage.from_params(Params("filtering", {})).max_state_age_s == MAX_STATE_AGE_S
    stage = FilteringStage.from_params(Params("filtering", {"max_state_age_s": 0.05}))
    assert stage.max_state_age_s == 0.05
    with pytest.raises(ConfigError, match="max_state_age_s"):
        FilteringStage.from_params(Params("filtering", {"max_state_age_s": 1.5}))
    with pytest.raises(ValueError, match="max_state_age_s"):
        FilteringStage(calibration.noise_current_A, max_state_age_s=-0.1)
