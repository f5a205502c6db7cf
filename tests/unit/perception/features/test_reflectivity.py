"""Reflectivity of features (:mod:`agent.perception.features.reflectivity`).

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.unit.perception.features.scans import (
    CYLINDER,
    WALL_1P5,
    Arc,
    Wall,
    features_of,
    simulate_scan,
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
