"""Filtering: gates, segmentation with the intensity gate, motion compensation, the stage."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.calibration.characterisation import head_centred_pose
from agent.calibration.table import Calibration
from agent.kinematics.trajectory import ConstantTwist, Trajectory
from agent.perception.evaluation import away_from_edges
from agent.perception.filtering import (
    FilterSettings,
    PoseHistory,
    SampleFlag,
    gate_and_segment,
    place_samples,
    segment_scan,
    validation_gates,
)
from agent.runtime import topics
from agent.runtime.messages import CalibratedScan, FilteredScan, Header, VehicleState
from agent.sensor.params import SensorParameters
from agent.sensor.samples import CalibratedScan as Samples
from agent.sim.simulator import ScanTruth, SensorSimulator
from agent.sim.world import World
from agent.stages.filtering_stage import FilteringStage

SETTINGS = FilterSettings()


def _scan(
    world: World,
    head: SensorParameters,
    calibration: Calibration,
    seed: int = 1,
    trajectory: Trajectory | None = None,
) -> tuple[Samples, ScanTruth]:
    sim = SensorSimulator(world, head, np.random.default_rng(seed))
    raw, truth = sim.sweep(trajectory=trajectory or head_centred_pose(head))
    return calibration.calibrate_scan(raw), truth


def _filter(scan: Samples, calibration: Calibration) -> tuple[np.ndarray, np.ndarray]:
    return gate_and_segment(
        scan.range_m, scan.sigma_m, scan.intensity_A, calibration.noise_current_A, SETTINGS
    )


def test_gates_name_each_reason() -> None:
    r = np.array([1.0, np.nan, 0.3, 2.8, 1.0, 1.0])
    intensity = np.array([2e-8, 1e-9, 3e-7, 3e-9, 1e-10, 2e-8])
    flags = validation_gates(r, intensity, 36.5e-12, SETTINGS)
    assert list(flags) == [
        SampleFlag.VALID,
        SampleFlag.NO_READING,
        SampleFlag.OUT_OF_RANGE,
        SampleFlag.OUT_OF_RANGE,
        SampleFlag.LOW_SNR,
        SampleFlag.VALID,
    ]


def test_linear_predictions_from_either_side() -> None:
    # A quadratic profile with unequal variances: each prediction is the weighted
    # straight-line fit of the four samples on its side, extrapolated to the sample
    # (checked against numpy.polyfit with weights 1/σ); NaN where a side has too few.
    from agent.perception.kernels import linear_predictions

    rng = np.random.default_rng(3)
    r = 1.0 + 0.01 * np.arange(12) ** 2
    var = rng.uniform(0.5, 2.0, 12) * 1e-6
    fwd, fvar, bwd, bvar = linear_predictions(r, var, 4)
    for k in range(12):
        for side, pred, pvar in (("before", fwd, fvar), ("after", bwd, bvar)):
            ks = np.arange(k - 4, k) if side == "before" else np.arange(k + 1, k + 5)
            if ks.min() < 0 or ks.max() > 11:
                assert math.isnan(pred[k]) and math.isnan(pvar[k])
                continue
            coef, cov = np.polyfit(ks - k, r[ks], 1, w=1 / np.sqrt(var[ks]), cov="unscaled")
            assert pred[k] == pytest.approx(coef[1], rel=1e-12)
            assert pvar[k] == pytest.approx(cov[1, 1], rel=1e-9)


def test_a_plain_wall_is_one_segment_with_nothing_dropped(
    head: SensorParameters, calibration: Calibration
) -> None:
    wall = World.build(walls=[(((1.4, -1.5), (1.0, 1.5)), 1.0)])
    for seed in range(5):
        scan, _ = _scan(wall, head, calibration, seed)
        flags, segment = _filter(scan, calibration)
        assert np.all(flags == SampleFlag.VALID), np.bincount(flags)
        assert set(segment) == {0}


def test_box_before_wall_is_three_surfaces_with_transitions_flagged(
    head: SensorParameters, calibration: Calibration
) -> None:
    world = World.build(
        walls=[(((2.0, -1.5), (2.0, 1.5)), 1.0)], boxes=[((1.2, 0.0), (0.4, 0.4), 0.0, 1.0)]
    )
    for seed in range(5):
        scan, truth = _scan(world, head, calibration, seed)
        flags, segment = _filter(scan, calibration)
        assert segment.max() == 2  # wall, box, wall
        # The missing part right of the box (return path blocked) is noise only: dropped.
        hidden = ~truth.visible
        assert np.all(flags[hidden] != SampleFlag.VALID)
        # Nothing kept lies far from its own surface.
        kept = flags == SampleFlag.VALID
        z = np.abs(scan.range_m - truth.range_m)[kept] / scan.sigma_m[kept]
        assert z.max() < 5.0


def test_without_the_intensity_gate_a_small_step_goes_unnoticed(
    head: SensorParameters, calibration: Calibration
) -> None:
    # A 3 cm step between a dark and a bright surface at 2 m: the range change is ~1σ, the
    # intensity change is large. The intensity validation gate breaks the scan there.
    world = World.build(walls=[(((2.0, -1.5), (2.0, 0.0)), 0.4), (((2.03, 0.0), (2.03, 1.5)), 1.6)])
    scan, _ = _scan(world, head, calibration)
    flags = validation_gates(scan.range_m, scan.intensity_A, calibration.noise_current_A, SETTINGS)
    _, with_gate = segment_scan(scan.range_m, scan.sigma_m, scan.intensity_A, flags, SETTINGS)
    loose = FilterSettings(intensity_ratio_gate=1e6)
    _, without = segment_scan(scan.range_m, scan.sigma_m, scan.intensity_A, flags, loose)

    def boundaries_near_step(segment: np.ndarray) -> int:
        theta = np.degrees(scan.scan_angle_rad)
        kept = segment >= 0
        change = np.flatnonzero(np.diff(segment[kept]) != 0)
        return int(np.sum(np.abs(theta[kept][change]) < 1.5))

    assert boundaries_near_step(with_gate) >= 1
    assert boundaries_near_step(without) == 0


def test_phantoms_and_losses_over_random_scenes(
    head: SensorParameters, calibration: Calibration
) -> None:
    """Valid samples > 5σ from truth ≤ 0.5 %; visible samples away from edges lost ≤ 2 %.

    40 scenes, ~9,000 valid samples: a rate of 0.5 % would show ~45; seen are a handful.
    """
    from tests.unit.calibration.test_calibration import _random_scene

    rng = np.random.default_rng(3)
    valid = phantoms = visible = lost = 0
    for i in range(40):
        sim = SensorSimulator(_random_scene(rng), head, rng)
        raw, truth = sim.sweep(direction=1 if i % 2 else -1, trajectory=head_centred_pose(head))
        scan = calibration.calibrate_scan(raw)
        flags, _ = _filter(scan, calibration)
        ok = flags == SampleFlag.VALID
        with np.errstate(invalid="ignore"):
            far = ~(np.abs(scan.range_m - truth.range_m) <= 5 * scan.sigma_m)
        valid += ok.sum()
        phantoms += (ok & far).sum()
        steady = away_from_edges(truth, (0.4, 2.5))
        visible += steady.sum()
        lost += (steady & ~ok).sum()
    assert valid > 5000 and visible > 5000
    assert phantoms / valid <= 0.005
    assert lost / visible <= 0.02


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
    scan, _ = _scan(wall, head, calibration, seed=4, trajectory=twist)
    flags, _ = _filter(scan, calibration)
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
        return (world_x - 1.6) / sigma_n

    compensated = normal_z(PoseHistory.sampled(twist, reference - 0.2, reference + 0.05))
    assert ok.sum() > 200
    assert 0.8 < np.sqrt(np.mean(compensated**2)) < 1.25
    bent = normal_z(PoseHistory())  # every sample placed as if taken at the reference pose
    assert np.mean(bent**2) > 4.0


def test_pose_history_interpolates_and_extrapolates() -> None:
    h = PoseHistory()
    h.add(0.0, 0.0, 0.0, 3.1, 1.0, 0.0)
    h.add(1.0, 1.0, 0.0, -3.1, 1.0, 0.0)  # yaw wraps: the shorter way is through ±π
    x, _, yaw = h.poses_at(np.array([0.5, 2.0]))
    assert x[0] == pytest.approx(0.5)
    assert abs(math.remainder(yaw[0] - math.pi, math.tau)) < 1e-9
    assert x[1] == pytest.approx(1.0 + math.cos(-3.1 + 2 * math.pi))  # 1 s more at 1 m/s
    h.add(0.5, 9.0, 9.0, 0.0, 0.0, 0.0)  # out of order: ignored
    assert len(h) == 2


def test_stage_filters_and_compensates(head: SensorParameters, calibration: Calibration) -> None:
    world = World.build(walls=[(((1.5, -2.0), (1.5, 2.0)), 1.0)])
    scan, _ = _scan(world, head, calibration)
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
