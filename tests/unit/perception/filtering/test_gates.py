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
