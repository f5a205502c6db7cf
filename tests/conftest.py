"""Shared fixtures: seeded randomness, the simulated head, the shipped calibration."""

from __future__ import annotations

import numpy as np
import pytest

from agent.calibration.table import Calibration, load_default_calibration
from agent.sensor.params import SensorParameters, simulated_head


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed-seed generator: every statistical test is repeatable."""
    return np.random.default_rng(20261121)


@pytest.fixture(scope="session")
def head() -> SensorParameters:
    return simulated_head()


@pytest.fixture(scope="session")
def calibration() -> Calibration:
    return load_default_calibration()
