"""Preparing a scan's samples (:mod:`agent.perception.features.samples`): what is
ignored, what is refused.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from agent.perception.features import extract_features, sample_kernels
from agent.perception.features.rows import VARB, WINT
from tests.unit.perception.features.scans import (
    BOX_AND_WALL,
    HALF_FOV,
    N_BEAMS,
    S_CARDBOARD,
    WALL_1P5,
    features_of,
    simulate_scan,
    stacked,
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


def test_ids_out_of_scan_order_are_grouped_by_id(rng: np.random.Generator) -> None:
    # Segment ids need not number the runs in scan order: the samples are grouped by id,
    # in scan order within each (a stable sort by id), each run stacked as it would be alone.
    scan = simulate_scan(BOX_AND_WALL, rng)
    in_order = stacked(scan)
    seg = scan["segment"]
    reversed_ids = np.where(seg >= 0, seg.max() - seg, -1).astype(np.int32)
    grouped = stacked({**scan, "segment": reversed_ids})
    assert len(in_order.runs) >= 3
    runs = list(reversed(in_order.runs))
    np.testing.assert_array_equal(
        grouped.index, np.concatenate([in_order.index[a:b] for a, b in runs])
    )
    assert [b - a for a, b in grouped.runs] == [b - a for a, b in runs]
    for (a, b), (c, d) in zip(runs, grouped.runs, strict=True):
        np.testing.assert_array_equal(grouped.rows[:, c:d], in_order.rows[:, a:b])
        np.testing.assert_array_equal(grouped.pair_cov[c : d - 1], in_order.pair_cov[a : b - 1])


def test_run_ends_and_neighbour_covariances(rng: np.random.Generator) -> None:
    s = stacked(simulate_scan(BOX_AND_WALL, rng), neighbour_correlation=0.13)
    ends = [a for a, _ in s.runs] + [b - 1 for _, b in s.runs]
    assert np.all(s.rows[WINT, ends] == 0.0)  # the end samples' intensities are not fitted
    sigma = np.sqrt(s.rows[VARB])
    expected = np.where(np.diff(s.index) == 1, 0.13 * sigma[:-1] * sigma[1:], 0.0)
    np.testing.assert_array_equal(s.pair_cov, expected)


def test_one_compiled_signature_for_writable_and_read_only_arrays(
    rng: np.random.Generator,
) -> None:
    # Decoded messages carry read-only arrays, the tests and the perception bench writable
    # ones: the kernel sees read-only ones either way, the signature warm_up loads (another
    # would be compiled, for seconds, at the first scan that brought it).
    scan = simulate_scan([WALL_1P5], rng)
    frozen = {k: np.array(v) if isinstance(v, np.ndarray) else v for k, v in scan.items()}
    for v in frozen.values():
        if isinstance(v, np.ndarray):
            v.flags.writeable = False
    kinds = [f.kind for f in features_of(frozen)]
    loaded = list(sample_kernels.stacked_samples.signatures)
    assert [f.kind for f in features_of(scan)] == kinds
    assert list(sample_kernels.stacked_samples.signatures) == loaded
