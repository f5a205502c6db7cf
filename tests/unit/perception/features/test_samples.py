"""Preparing a scan's samples (:mod:`agent.perception.features.samples`): what is
ignored, what is refused.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from agent.perception.features import extract_features
from tests.unit.perception.features.scans import (
    HALF_FOV,
    N_BEAMS,
    S_CARDBOARD,
    WALL_1P5,
    features_of,
    simulate_scan,
)


def _empty_args(n: int) -> dict[str, Any]:
    return {
        "points_xy": np.full((n, 2), np.nan),
        "covariance": np.full((n, 2, 2), np.nan),
        "segment": np.full(n, -1, dtype=np.int32),
        "flag": np.ones(n, dtype=np.uint8),
        "intensity_A": np.zeros(n),
        "range_m": np.full(n, np.nan),
        "origin_xy": np.zeros((n, 2)),
        "beam_angle_rad": np.linspace(-HALF_FOV, HALF_FOV, n),
        "signal_constant_Am2": S_CARDBOARD,
    }


def test_empty_scan() -> None:
    assert extract_features(**_empty_args(0)) == []


def test_all_samples_dropped() -> None:
    assert extract_features(**_empty_args(N_BEAMS)) == []


def test_nan_in_samples_marked_valid_is_ignored(rng: np.random.Generator) -> None:
    scan = simulate_scan([WALL_1P5], rng)
    scan["points_xy"][10] = np.nan
    scan["covariance"][20] = np.inf
    scan["intensity_A"][30] = np.nan
    features = features_of(scan)
    assert [f.kind for f in features] == ["segment"]
    assert 10 not in features[0].samples and 20 not in features[0].samples


def test_mismatched_shapes_are_a_value_error(rng: np.random.Generator) -> None:
    scan = simulate_scan([WALL_1P5], rng)
    scan["range_m"] = scan["range_m"][:-1]
    with pytest.raises(ValueError, match="range_m"):
        features_of(scan)
