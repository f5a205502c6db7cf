"""The chapter's calibration procedure, run against the simulated head.

* :func:`scan_calibration_planes` records fig. 6.7's data: planar targets at known distances
  across and beyond the depth of field, each swept many times in both directions.
* :func:`run_calibration` builds the look-up table from them, then characterises the sensor
  with it (``S``, ``I_n``, ``fd``; :mod:`agent.calibration.characterisation`) and stores those
  constants with the table.

Targets are placed in a head-centred world (:mod:`agent.sim.targets`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from agent.arrays import FloatArray
from agent.calibration.build import PlaneObservations, TableSettings, calibration_from_observations
from agent.calibration.characterisation import CharacterisationResult, characterise
from agent.calibration.progress import Progress
from agent.calibration.table import Calibration, delay_corrected
from agent.sensor.detection import detection_delay_s
from agent.sensor.lep import position_from_currents
from agent.sensor.params import SensorParameters, nominal_sensor
from agent.sim.simulator import SensorSimulator
from agent.sim.targets import head_centred_pose, plane_world


def calibration_plane_distances(
    n_planes: int = 48, near_m: float = 0.30, far_m: float = 3.45
) -> FloatArray:
    """Target distances spaced evenly in inverse distance (so evenly on the detector).

    They reach past both ends of the detector at every scan angle, so the table covers all of it.
    """
    return 1.0 / np.linspace(1.0 / far_m, 1.0 / near_m, n_planes)


def scan_calibration_planes(
    head: SensorParameters,
    rng: np.random.Generator,
    distances_m: Sequence[float] | FloatArray,
    n_sweeps: int,
    nominal: SensorParameters | None = None,
    progress: Progress | None = None,
) -> list[PlaneObservations]:
    """Sweep the full window ``n_sweeps`` times (alternating direction) over each plane.

    Angles and times are corrected for the detection delay with the nominal filter design
    (as the calibration stage does), so the table is indexed by the angle a sample measures.
    """
    nominal = nominal if nominal is not None else nominal_sensor()
    pose = head_centred_pose(head)
    delay = detection_delay_s(nominal)
    out = []
    for i, z in enumerate(distances_m):
        sim = SensorSimulator(plane_world(float(z)), head, rng)
        thetas, us, signals = [], [], []
        for s in range(n_sweeps):
            raw, _ = sim.sweep(
                direction=1 if s % 2 == 0 else -1,
                trajectory=pose,
                start_time_s=s * head.sweep_period_s,
            )
            u, intensity = position_from_currents(raw.current_1_A, raw.current_2_A)
            _, theta = delay_corrected(raw, delay, nominal.scan_rate_rad_s)
            thetas.append(theta)
            us.append(u)
            signals.append(intensity)
        out.append(
            PlaneObservations(
                float(z), np.concatenate(thetas), np.concatenate(us), np.concatenate(signals)
            )
        )
        if progress is not None:
            progress(i + 1, len(distances_m))
    return out


@dataclass(frozen=True)
class CalibrationSettings:
    """Sizes of the calibration run."""

    n_planes: int = 48
    n_sweeps: int = 32
    table: TableSettings = field(default_factory=TableSettings)
    characterisation_samples: int = 1000


def run_calibration(
    head: SensorParameters,
    rng: np.random.Generator,
    settings: CalibrationSettings | None = None,
    progress: Progress | None = None,
) -> tuple[Calibration, CharacterisationResult]:
    """Calibrate the head: plane scans to a look-up table, then characterise ``S, I_n, fd``."""
    settings = settings if settings is not None else CalibrationSettings()
    nominal = nominal_sensor()
    distances = calibration_plane_distances(settings.n_planes)
    planes = scan_calibration_planes(head, rng, distances, settings.n_sweeps, nominal, progress)
    metadata: dict[str, Any] = {
        "planes_m": [round(float(z), 6) for z in distances],
        "sweeps_per_plane": settings.n_sweeps,
        "curve_degree": settings.table.curve_degree,
    }
    # Build the table once; the constants come from characterising with it.
    provisional = calibration_from_observations(
        planes,
        signal_constant_Am2=nominal.signal_constant_Am2,
        noise_current_A=nominal.noise_current_A,
        fd_m2=nominal.fd_m2,
        nominal=nominal,
        settings=settings.table,
        metadata=metadata,
    )
    result = characterise(provisional, head, rng, settings.characterisation_samples)
    final = replace(
        provisional,
        signal_constant_Am2=result.fit_S_Am2,
        noise_current_A=result.fit_I_n_A,
        fd_m2=result.fit_fd_m2,
    )
    return final, result
