"""The surfaces of one run (:mod:`agent.perception.features.surfaces`): a cylinder beside
another surface on one run comes out whole, once.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import numpy as np
import pytest

from agent.perception.features import Feature
from tests.unit.perception.features.scans import (
    Arc,
    Wall,
    features_of,
    nees,
    of_kind,
    simulate_scan,
)


def test_cylinder_on_one_run_with_a_wall_comes_out_whole() -> None:
    # A half-sunk pillar (r = 0.1 m, centre 5 cm in front of the wall) on a run the filter did
    # not break: the splitter's pieces are offered to the cylinder test before being cut.
    scene = [Arc((1.75, 0.0), 0.1, obj=1), Wall((1.8, -2.0), (1.8, 2.0), obj=0)]
    for seed in range(20):
        scan = simulate_scan(scene, np.random.default_rng(seed))
        scan["segment"][scan["segment"] >= 0] = 0
        features = features_of(scan)
        assert [f.kind for f in features] == ["segment", "cylinder", "segment"]
        cyl = features[1]
        # χ²₃ < 16.3: the 99.9 % point, so 20 scans pass together 98 % of the time.
        assert nees(cyl.params - np.array([1.75, 0.0, 0.1]), cyl.covariance) < 16.3


PILLAR = Arc((1.9, 0.0), 0.29, obj=1)  # σ 3-8 mm along its run at 1.6-1.9 m


def _cylinders_on_one_run(scene: list[Wall | Arc], seeds: int = 20) -> list[list[Feature]]:
    """Features of ``seeds`` scans of ``scene`` on one run (no break from the filter)."""
    out = []
    for seed in range(seeds):
        scan = simulate_scan(scene, np.random.default_rng(seed))
        scan["segment"][scan["segment"] >= 0] = 0
        out.append(features_of(scan))
    return out


@pytest.mark.parametrize(
    ("scene", "kinds"),
    [
        # Sunk 10 cm into the wall behind it: before the circles were joined, every scan
        # reported it twice (two circles split where the wall's samples left the circle).
        ([PILLAR, Wall((2.15, -1.0), (2.15, 1.0), obj=0)], ["segment", "cylinder", "segment"]),
        # A face square to the beams leaving its left silhouette: reported twice in 45 of
        # 60 scans before.
        ([PILLAR, Wall((1.9, 0.2), (1.9, 0.6), obj=0)], None),
    ],
    ids=["sunk in a wall", "beside a face"],
)
def test_a_large_far_cylinder_beside_a_surface_is_one_cylinder(
    scene: list[Wall | Arc], kinds: list[str] | None
) -> None:
    truth = np.array([*PILLAR.center, PILLAR.radius])
    for features in _cylinders_on_one_run(scene):
        if kinds is not None:
            assert [f.kind for f in features] == kinds
        cylinders = of_kind(features, "cylinder")
        assert len(cylinders) == 1
        # χ²₃ < 16.3: the 99.9 % point, so 20 scans pass together 98 % of the time.
        assert nees(cylinders[0].params - truth, cylinders[0].covariance) < 16.3
