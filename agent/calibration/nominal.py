"""Range before calibration: the nominal equations, for the head as drawn.

The drawing has ``fd = f·d``, the drawn detector position and a linear LEP; the real head
differs from it, which is what the calibration (:mod:`agent.calibration.table`) corrects.
"""

from __future__ import annotations

import numpy as np

from agent.arrays import FloatArray
from agent.sensor.lep import image_position, position_sigma
from agent.sensor.params import SensorParameters, nominal_sensor
from agent.sensor.triangulation import synchronised_range, synchronised_range_gain


def nominal_ranges(
    scan_angle_rad: FloatArray,
    position_norm: FloatArray,
    intensity_A: FloatArray,
    params: SensorParameters | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Range and σ from the nominal equations alone: what the agent has before calibration.

    ``r = (fd/p)·cos θ + d·sin θ`` (eq. 6.5) with the drawn ``fd = f·d`` and detector offset.
    """
    params = params if params is not None else nominal_sensor()
    p = image_position(position_norm, params)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = synchronised_range(p, scan_angle_rad, params.fd_m2, params.baseline_m)
        gain = synchronised_range_gain(r, scan_angle_rad, params.fd_m2, params.baseline_m)
        sigma_p = (
            position_sigma(intensity_A, params.noise_current_A) * 0.5 * params.detector_length_m
        )
        sigma = sigma_p / gain
    return r, sigma
