"""Building the calibration's look-up table from observations of planar targets.

As in the chapter (section 6.6.1, fig. 6.7): planar targets at known distances are scanned
across the whole field of view; for every scan angle the recorded image positions of the
targets, paired with their known ranges, give inverse range as a function of image position,
tabulated on the grid of :class:`~agent.calibration.table.Calibration`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.polynomial import Chebyshev

from agent.arrays import FloatArray
from agent.calibration.table import Calibration
from agent.sensor.params import SensorParameters, nominal_sensor


@dataclass(frozen=True)
class PlaneObservations:
    """Calibrated-time samples of one planar target at a known perpendicular distance.

    The plane is perpendicular to the head's x axis at ``distance_m`` from the centre of
    scanning, so a beam at scan angle θ meets it at range ``distance_m / cos θ``.
    """

    distance_m: float
    scan_angle_rad: FloatArray
    position_norm: FloatArray
    intensity_A: FloatArray


@dataclass(frozen=True)
class TableSettings:
    """How finely the look-up table is tabulated and how the plane curves are smoothed.

    ``curve_degree``: Chebyshev degree of each plane's image position against scan angle
    (a smooth curve, fig. 6.7; fitting it averages thousands of samples per plane).
    ``max_extrapolation``: how far, in normalised position, the table may extend beyond the
    nearest and farthest planes seen at an angle (inverse range is nearly linear in position).
    ``max_angle_extrapolation_rad``: likewise in scan angle; the outermost samples of a full
    sweep sit half a sample spacing inside ±20°.
    ``min_snr``: samples whose signal is below this many noise currents are left out; where a
    plane images off the detector the electrodes carry only noise, and a noise-only sample can
    still fall inside [-1, 1].
    """

    n_scan_angles: int = 161
    n_positions: int = 201
    curve_degree: int = 8
    max_extrapolation: float = 0.05
    max_angle_extrapolation_rad: float = 0.005
    min_samples_per_plane: int = 64
    min_snr: float = 20.0


def fit_plane_curve(
    obs: PlaneObservations, settings: TableSettings, noise_current_A: float
) -> tuple[Chebyshev, float, float] | None:
    """Weighted Chebyshev fit of image position against scan angle for one plane.

    Weights are ``I_s`` (``1/σ_u`` up to a constant, eq. 6.14). Returns the curve and the
    angle interval it covers, or ``None`` if the plane gave too few readings.
    """
    ok = np.isfinite(obs.position_norm) & (obs.intensity_A > settings.min_snr * noise_current_A)
    if np.count_nonzero(ok) < settings.min_samples_per_plane:
        return None
    theta = obs.scan_angle_rad[ok]
    # A plane seen over only part of the scan (its image runs off the detector) gets a lower
    # degree, in proportion: a high-degree fit over a sliver of angle is unconstrained.
    full_span = 2.0 * float(np.max(np.abs(obs.scan_angle_rad)))
    span = float(theta.max() - theta.min())
    degree = max(1, min(settings.curve_degree, math.ceil(settings.curve_degree * span / full_span)))
    curve = Chebyshev.fit(theta, obs.position_norm[ok], degree, w=obs.intensity_A[ok])
    return curve, float(theta.min()), float(theta.max())


def build_table(
    observations: list[PlaneObservations],
    scan_half_angle_rad: float,
    noise_current_A: float,
    settings: TableSettings | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Build the inverse-range table from plane observations.

    Returns ``(scan_angle_grid, position_grid, inverse_range)``; see :class:`Calibration`.
    """
    # Imported here: the processes that only load and apply a calibration never build one,
    # and scipy would add about 0.5 s to each one's start (five start at once on two cores).
    from scipy.interpolate import CubicSpline

    settings = settings if settings is not None else TableSettings()
    theta_grid = np.linspace(-scan_half_angle_rad, scan_half_angle_rad, settings.n_scan_angles)
    u_grid = np.linspace(-1.0, 1.0, settings.n_positions)
    curves = []
    for obs in observations:
        fitted = fit_plane_curve(obs, settings, noise_current_A)
        if fitted is not None:
            curves.append((obs.distance_m, *fitted))
    if len(curves) < 4:
        raise ValueError(f"calibration needs readings from at least 4 planes, got {len(curves)}")
    table = np.full((theta_grid.size, u_grid.size), np.nan)
    for i, theta in enumerate(theta_grid):
        reach_rad = settings.max_angle_extrapolation_rad
        nodes = [
            (curve(theta), math.cos(theta) / z)
            for z, curve, lo, hi in curves
            if lo - reach_rad <= theta <= hi + reach_rad
        ]
        if len(nodes) < 4:
            continue
        u_k, q_k = np.array(sorted(nodes)).T
        if np.any(np.diff(u_k) <= 0) or np.any(np.diff(q_k) <= 0):
            raise ValueError(
                f"calibration curves cross at scan angle {math.degrees(theta):.2f}°"
                " (image position must fall monotonically with range)"
            )
        spline = CubicSpline(u_k, q_k, bc_type="natural")
        reach = (u_grid >= u_k[0] - settings.max_extrapolation) & (
            u_grid <= u_k[-1] + settings.max_extrapolation
        )
        table[i, reach] = spline(u_grid[reach])
    return theta_grid, u_grid, table


def calibration_from_observations(
    observations: list[PlaneObservations],
    *,
    signal_constant_Am2: float,
    noise_current_A: float,
    fd_m2: float,
    nominal: SensorParameters | None = None,
    settings: TableSettings | None = None,
    metadata: dict[str, Any] | None = None,
) -> Calibration:
    """A :class:`Calibration` from plane observations and characterised constants."""
    from agent.sensor.detection import detection_delay_s  # scipy.signal: see build_table

    nominal = nominal if nominal is not None else nominal_sensor()
    theta_grid, u_grid, table = build_table(
        observations, nominal.scan_half_angle_rad, noise_current_A, settings
    )
    return Calibration(
        scan_angle_grid_rad=theta_grid,
        position_grid=u_grid,
        inverse_range_per_m=table,
        signal_constant_Am2=signal_constant_Am2,
        noise_current_A=noise_current_A,
        fd_m2=fd_m2,
        detection_delay_s=detection_delay_s(nominal),
        scan_rate_rad_s=nominal.scan_rate_rad_s,
        scan_angle_sigma_rad=nominal.scan_angle_repeatability_rad,
        metadata=dict(metadata or {}),
    )
