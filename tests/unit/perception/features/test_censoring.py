"""Walls at the far end of the depth of field: the samples the filter keeps there are
censored (their measured range inside the limit), and a line piece leaves out those that
its own line puts within ``FeatureSettings.censor_margin_sigma`` of their σ of the limit
(:meth:`agent.perception.features.surfaces.Surfaces.uncensored`).

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from agent.perception.features import FeatureSettings
from tests.unit.perception.features.scans import (
    UNBIASED,
    Wall,
    features_of,
    line_error,
    line_truth,
    nees,
    of_kind,
    simulate_scan,
)

FAR_M = FeatureSettings().depth_of_field_m[1]
SCANS = 60
# Mean of SCANS NEES (2 dof) of an honest covariance: 2 ± 3·sqrt(2·2/SCANS).
BAND = 3.0 * np.sqrt(4.0 / SCANS)
NOT_TRIMMED = replace(UNBIASED, depth_of_field_m=(0.0, 1e9))


def censored_scan(scene: list[Wall], seed: int) -> dict[str, Any]:
    """A synthetic scan with the samples whose *measured* range is beyond the far limit
    dropped, as the filter's depth-of-field gate drops them."""
    scan = simulate_scan(scene, np.random.default_rng(seed))
    out = scan["range_m"] > FAR_M
    scan["flag"] = np.where(out, 3, scan["flag"]).astype(np.uint8)
    scan["segment"] = np.where(out, -1, scan["segment"]).astype(np.int32)
    return scan


def mean_nees(wall: Wall, settings: FeatureSettings) -> float:
    truth = line_truth(wall.p0, wall.p1)
    values = [
        nees(line_error(f, truth), f.covariance[:2, :2])
        for seed in range(SCANS)
        for f in of_kind(features_of(censored_scan([wall], seed), settings=settings), "segment")
    ]
    assert len(values) >= SCANS
    return float(np.mean(values))


# The centre of scanning is at (0.3, 0): square-on at 2.35 m from it (its ends at 2.5 m and
# beyond), and oblique from 2.2 m to beyond the limit.
@pytest.mark.parametrize(
    "wall",
    [Wall((2.65, -1.0), (2.65, 1.0)), Wall((2.5, -0.7), (3.2, 0.7))],
    ids=["square-on", "oblique"],
)
def test_lines_at_the_far_limit_are_consistent(wall: Wall) -> None:
    assert abs(mean_nees(wall, UNBIASED) - 2.0) < BAND
    # Without leaving out the censored samples: 3.7 and 4.8.
    assert mean_nees(wall, NOT_TRIMMED) > 2.0 + BAND


def test_a_line_inside_the_depth_of_field_is_not_trimmed() -> None:
    wall = Wall((1.2, -0.4), (1.6, 0.4))
    for seed in range(5):
        scan = simulate_scan([wall], np.random.default_rng(seed))
        kept = of_kind(features_of(scan), "segment")
        whole = of_kind(features_of(scan, settings=NOT_TRIMMED), "segment")
        assert [f.samples.tolist() for f in kept] == [f.samples.tolist() for f in whole]


def test_a_line_wholly_in_the_censored_band_is_not_reported() -> None:
    # 2.4-2.5 m from the centre of scanning, where σ is about 5 cm: every sample within 2σ.
    wall = Wall((2.72, -0.3), (2.72, 0.3))
    for seed in range(5):
        scan = censored_scan([wall], seed)
        assert of_kind(features_of(scan, settings=NOT_TRIMMED), "segment")
        assert not of_kind(features_of(scan), "segment")


def test_settings_check_the_depth_of_field() -> None:
    with pytest.raises(ValueError, match="depth_of_field_m"):
        FeatureSettings(depth_of_field_m=(2.5, 0.4))
    with pytest.raises(ValueError, match="censor_margin_sigma"):
        FeatureSettings(censor_margin_sigma=-1.0)


def test_the_depth_of_field_is_the_filters() -> None:
    from agent.perception.filtering.settings import FilterSettings

    assert FeatureSettings().depth_of_field_m == FilterSettings().depth_of_field_m
