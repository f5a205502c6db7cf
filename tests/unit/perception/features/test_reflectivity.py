"""Reflectivity of features (:mod:`agent.perception.features.reflectivity`).

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.perception.features import reflectivity_kernels
from agent.perception.features.circles import Meeting
from agent.perception.features.rows import BX, BY, OX, OY, REFL, VX, VY
from tests.unit.perception.features.scans import (
    CYLINDER,
    WALL_1P5,
    Arc,
    Wall,
    features_of,
    simulate_scan,
    stacked,
)


@pytest.mark.parametrize("reflectivity", [0.5, 2.0])
def test_reflectivity_of_a_wall(rng: np.random.Generator, reflectivity: float) -> None:
    wall = Wall(WALL_1P5.p0, WALL_1P5.p1, reflectivity=reflectivity)
    (seg,) = features_of(simulate_scan([wall], rng))
    assert seg.reflectivity == pytest.approx(reflectivity, rel=0.1)


def test_reflectivity_of_every_kind(rng: np.random.Generator) -> None:
    scene: list[Wall | Arc] = [
        Arc(CYLINDER.center, CYLINDER.radius, reflectivity=0.7, obj=1),
        Wall((2.3, -2.0), (2.3, 2.0), reflectivity=1.5, obj=0),
    ]
    for f in features_of(simulate_scan(scene, rng)):
        expected = 1.5 if f.kind == "segment" else 0.7  # edges: the nearer surface's
        assert f.reflectivity == pytest.approx(expected, rel=0.1), f.kind


def _numpy_reflectivities(rows: np.ndarray, cos_view: np.ndarray, min_cos: float) -> np.ndarray:
    usable = cos_view >= min_cos
    rho = rows[REFL][usable] / cos_view[usable]
    return np.asarray(rho[np.isfinite(rho)])


def test_kernels_are_the_numpy_formulation(rng: np.random.Generator) -> None:
    # Same operations in the same order: equal to the last bit.
    rows = stacked(simulate_scan([CYLINDER], rng)).rows
    m = rows.shape[1]
    alpha, (cx, cy, r), min_cos = 2.9, (1.5, 0.01, 0.11), 0.2
    on_line = np.abs(rows[VX] * math.cos(alpha) + rows[VY] * math.sin(alpha))
    meet = Meeting.of(rows[OX], rows[OY], rows[BX], rows[BY], cx, cy, r)
    on_circle = np.maximum(meet.ux * rows[VX] + meet.uy * rows[VY], 0.0)
    got = reflectivity_kernels.line_reflectivities(rows, 0, m, alpha, min_cos)
    np.testing.assert_array_equal(got, _numpy_reflectivities(rows, on_line, min_cos))
    got = reflectivity_kernels.circle_reflectivities(rows, 0, m, cx, cy, r, min_cos)
    np.testing.assert_array_equal(got, _numpy_reflectivities(rows, on_circle, min_cos))
    assert got.size > 10
    for values in (got, got[:-1], got[:1]):
        assert reflectivity_kernels.median(values) == np.median(values)
