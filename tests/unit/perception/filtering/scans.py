"""Calibrated scans of simulated worlds, and the filter's gates and segmentation over them."""

from __future__ import annotations

import numpy as np

from agent.calibration.table import Calibration
from agent.kinematics.trajectory import Trajectory
from agent.perception.filtering import FilterSettings, gate_and_segment
from agent.sensor.params import SensorParameters
from agent.sensor.samples import CalibratedScan as Samples
from agent.sim.simulator import ScanTruth, SensorSimulator
from agent.sim.targets import head_centred_pose
from agent.sim.world import World

SETTINGS = FilterSettings()


def calibrated_scan(
    world: World,
    head: SensorParameters,
    calibration: Calibration,
    seed: int = 1,
    trajectory: Trajectory | None = None,
) -> tuple[Samples, ScanTruth]:
    sim = SensorSimulator(world, head, np.random.default_rng(seed))
    raw, truth = sim.sweep(trajectory=trajectory or head_centred_pose(head))
    return calibration.calibrate_scan(raw), truth


def gate_and_segment_scan(scan: Samples, calibration: Calibration) -> tuple[np.ndarray, np.ndarray]:
    return gate_and_segment(
        scan.range_m, scan.sigma_m, scan.intensity_A, calibration.noise_current_A, SETTINGS
    )
