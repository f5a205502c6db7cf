"""Building the look-up table from plane observations, on noise-free planes of the drawn head."""

from __future__ import annotations

import numpy as np
import pytest

from agent.calibration.build import PlaneObservations, TableSettings, build_table, fit_plane_curve
from agent.sensor.lep import spot_position
from agent.sensor.params import SensorParameters, nominal_sensor

NOISE_CURRENT_A = 36.5e-12
STRONG_SIGNAL_A = 1e-8  # 270 noise currents: well above TableSettings.min_snr


def _plane(distance_m: float, params: SensorParameters, n: int = 400) -> PlaneObservations:
    """Exact image positions of a plane across the sweep; off the detector is no reading."""
    theta = np.linspace(-params.scan_half_angle_rad, params.scan_half_angle_rad, n)
    u = spot_position(distance_m / np.cos(theta), theta, params)
    u = np.where(np.abs(u) <= 1.0, u, np.nan)
    return PlaneObservations(distance_m, theta, u, np.full(n, STRONG_SIGNAL_A))


def test_table_reproduces_the_planes_it_was_built_from() -> None:
    params = nominal_sensor()
    distances = 1.0 / np.linspace(1.0 / 3.45, 1.0 / 0.30, 24)
    theta_grid, u_grid, table = build_table(
        [_plane(float(z), params) for z in distances], params.scan_half_angle_rad, NOISE_CURRENT_A
    )
    assert table.shape == (theta_grid.size, u_grid.size)
    # On the grid's centre row (θ = 0), inverse range at a plane's image position is 1/z; on
    # axis it is exactly linear in position for the drawn head (eq. 6.5), so interpolation and
    # the spline add only rounding.
    centre = theta_grid.size // 2
    assert theta_grid[centre] == 0.0
    for z in (0.6, 1.0, 2.0):
        u = float(spot_position(z, 0.0, params))
        q = np.interp(u, u_grid, table[centre])
        assert q == pytest.approx(1.0 / z, rel=1e-6)


def test_too_few_planes_or_readings_are_refused() -> None:
    params = nominal_sensor()
    three = [_plane(z, params) for z in (0.6, 1.0, 2.0)]
    with pytest.raises(ValueError, match="at least 4 planes"):
        build_table(three, params.scan_half_angle_rad, NOISE_CURRENT_A)
    settings = TableSettings()
    faint = PlaneObservations(
        1.0, three[1].scan_angle_rad, three[1].position_norm, np.full(400, 1e-12)
    )  # below min_snr noise currents: a noise-only reading
    assert fit_plane_curve(faint, settings, NOISE_CURRENT_A) is None
    assert fit_plane_curve(three[1], settings, NOISE_CURRENT_A) is not None
