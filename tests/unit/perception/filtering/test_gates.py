"""Validation gates (:mod:`agent.perception.filtering.gates`)."""

from __future__ import annotations

import numpy as np

from agent.perception.filtering import SampleFlag, validation_gates
from tests.unit.perception.filtering.scans import SETTINGS


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


def test_compiled_gates_are_the_numpy_formulation(rng: np.random.Generator) -> None:
    r = rng.uniform(0.0, 3.0, 500)
    r[rng.integers(0, 500, 40)] = np.nan
    r[rng.integers(0, 500, 5)] = np.inf
    intensity = rng.uniform(-1e-10, 1e-8, 500)
    intensity[rng.integers(0, 500, 10)] = np.nan
    noise = 36.5e-12
    near, far = SETTINGS.depth_of_field_m
    expected = np.full(r.shape, SampleFlag.VALID, dtype=np.uint8)
    with np.errstate(invalid="ignore"):
        expected[(r < near) | (r > far)] = SampleFlag.OUT_OF_RANGE
        expected[intensity < SETTINGS.min_snr * noise] = SampleFlag.LOW_SNR
    expected[~np.isfinite(r)] = SampleFlag.NO_READING
    np.testing.assert_array_equal(validation_gates(r, intensity, noise, SETTINGS), expected)
