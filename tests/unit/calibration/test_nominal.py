"""The nominal equations: what the agent has before calibration."""

from __future__ import annotations

import numpy as np

from agent.calibration.nominal import nominal_ranges
from agent.sensor.lep import spot_position
from agent.sensor.params import nominal_sensor


def test_nominal_equations_are_right_for_a_head_built_to_the_drawing() -> None:
    nominal = nominal_sensor()
    theta = np.radians(np.linspace(-20, 20, 5))
    u = spot_position(1.2, theta, nominal)
    r, s = nominal_ranges(theta, u, np.full(5, 1e-8), nominal)
    np.testing.assert_allclose(r, 1.2, rtol=1e-12)
    assert np.all(s > 0)
