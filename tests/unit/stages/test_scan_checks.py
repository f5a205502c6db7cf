"""A filtered scan that no filtering stage would send is counted and dropped by the stages
that read it (agent.stages.scan_checks): found by `sensor-agent fuzz`, where a covariance
with a negative variance along a direction reached the features' censoring margin as NaN."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from agent.runtime import topics
from agent.runtime.messages import FilteredScan
from agent.stages.features_stage import FeaturesStage
from agent.stages.scan_checks import filtered_scan_problem
from tests.unit.runtime.test_messages import example


def _scan() -> FilteredScan:
    scan = example("filtered_scan/1")
    assert isinstance(scan, FilteredScan)
    return scan


def _with_covariance(scan: FilteredScan, k: int, cov: list[list[float]]) -> FilteredScan:
    c = scan.covariance.copy()
    c[k] = cov
    return dataclasses.replace(scan, covariance=c)


def test_a_well_formed_scan_passes() -> None:
    assert filtered_scan_problem(_scan()) is None


@pytest.mark.parametrize(
    ("cov", "why"),
    [
        ([[1e-4, 2e-4], [2e-4, 1e-4]], "positive semi-definite"),  # a negative eigenvalue
        ([[-1e-4, 0.0], [0.0, 1e-4]], "positive semi-definite"),
        ([[1e-4, 1e-5], [-1e-5, 1e-4]], "symmetric"),
        ([[np.nan, 0.0], [0.0, 1e-4]], "not finite"),
    ],
)
def test_a_valid_sample_with_a_bad_covariance_is_refused(cov: list[list[float]], why: str) -> None:
    scan = _scan()
    k = int(np.flatnonzero(scan.flag == 0)[0])
    problem = filtered_scan_problem(_with_covariance(scan, k, cov))
    assert problem is not None and why in problem


def test_the_features_stage_counts_and_drops_it() -> None:
    scan = _scan()
    k = int(np.flatnonzero(scan.flag == 0)[0])
    bad = _with_covariance(scan, k, [[1e-4, 2e-4], [2e-4, 1e-4]])
    stage = FeaturesStage(signal_constant_Am2=2.59e-8)
    assert stage.handle(topics.FILTERED_SCAN, bad, 0.0) == []
    assert stage.counters()["filtered_scan_malformed"] == 1
    assert stage.handle(topics.FILTERED_SCAN, scan, 0.0)  # a good one goes through
