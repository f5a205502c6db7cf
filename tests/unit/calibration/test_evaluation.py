"""Range error before and after calibration: what the shipped table removes."""

from __future__ import annotations

import numpy as np

from agent.calibration.evaluation import evaluate_calibration
from agent.calibration.table import Calibration
from agent.sensor.params import SensorParameters


def test_shipped_calibration_removes_the_head_error(
    calibration: Calibration, head: SensorParameters
) -> None:
    """Done means: calibrated bias below 0.2 σ everywhere on the grid; uncalibrated far worse.

    9 ranges x 9 angle bins, 60 sweeps: ~1700 samples a cell, so a cell's bias estimate has a
    standard error of 0.025 σ and the largest of 81 about 0.07 σ: 0.2 σ leaves room for
    a real bias of over 0.1 σ while failing a table that is off by more.
    """
    after, before = evaluate_calibration(calibration, head, np.random.default_rng(8), n_sweeps=60)
    assert np.all(after.count > 1000)
    assert np.nanmax(np.abs(after.bias_sigma)) < 0.2
    assert np.nanmin(np.abs(before.bias_sigma)) > 2.0  # nominal equations: 3 to 380 σ
    # The predicted σ is honest cell by cell: RMS of (error/σ) near 1.
    assert np.all((after.rms_sigma > 0.9) & (after.rms_sigma < 1.12))
