"""The calibration procedure: plane scans to a usable table and constants."""

from __future__ import annotations

import numpy as np
import pytest

from agent.calibration.evaluation import evaluate_calibration
from agent.calibration.procedure import CalibrationSettings, run_calibration
from agent.sensor.params import SensorParameters


def test_calibration_procedure_builds_a_usable_table(head: SensorParameters) -> None:
    rng = np.random.default_rng(4)
    cal, res = run_calibration(
        head, rng, CalibrationSettings(n_planes=32, n_sweeps=4, characterisation_samples=300)
    )
    assert res.fit_fd_m2 == pytest.approx(head.fd_m2, rel=0.05)
    assert cal.noise_current_A == pytest.approx(head.noise_current_A, rel=0.1)
    after, _ = evaluate_calibration(cal, head, rng, ranges_m=(0.6, 1.2, 2.0), n_sweeps=10)
    assert np.nanmax(np.abs(after.bias_sigma)) < 0.3  # few sweeps: a noisier table
