"""The filtering stage over the filter's steps: gates, segmentation, compensation."""

from __future__ import annotations

import numpy as np

from agent.calibration.table import Calibration
from agent.runtime import topics
from agent.runtime.messages import CalibratedScan, FilteredScan, Header, VehicleState
from agent.sensor.params import SensorParameters
from agent.sim.world import World
from agent.stages.filtering_stage import FilteringStage
from tests.unit.perception.filtering.scans import calibrated_scan


def test_stage_filters_and_compensates(head: SensorParameters, calibration: Calibration) -> None:
    world = World.build(walls=[(((1.5, -2.0), (1.5, 2.0)), 1.0)])
    scan, _ = calibrated_scan(world, head, calibration)
    msg = CalibratedScan(
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
    stage = FilteringStage(calibration.noise_current_A)
    [(topic, out)] = stage.handle(topics.CALIBRATED_SCAN, msg, 0.0)
    assert topic == topics.FILTERED_SCAN and isinstance(out, FilteredScan)
    assert not out.motion_compensated and out.sweep_index == 3
    assert np.all(out.flag == 0) and np.all(out.segment == 0)
    # Points: the wall at 1.5 m ahead of the centre of scanning, in the vehicle frame.
    assert np.allclose(out.points_xy[:, 0], 1.5 + head.mount_offset_m, atol=0.06)  # 5σ
    state = VehicleState(
        header=Header(stamp_ns=0),
        x_m=0.0,
        y_m=0.0,
        yaw_rad=0.0,
        speed_m_s=0.0,
        yaw_rate_rad_s=0.0,
        pose_covariance=np.eye(3) * 1e-4,
        intent_xy=np.zeros((0, 2)),
    )
    assert stage.handle(topics.VEHICLE_STATE, state, 0.0) == []
    [(_, again)] = stage.handle(topics.CALIBRATED_SCAN, msg, 0.0)
    assert isinstance(again, FilteredScan) and again.motion_compensated
    assert stage.counters()["scans"] == 2 and stage.counters()["samples_valid"] == 512
