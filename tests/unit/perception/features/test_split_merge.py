"""Split and merge (:mod:`agent.perception.features.split_merge`): splits judged by each
point's own σ.

The synthetic scans and the tolerances of statistical checks: :mod:`.scans`.
"""

from __future__ import annotations

import math

import numpy as np

from tests.unit.perception.features.scans import Wall, features_of, simulate_scan


def test_noisy_far_points_do_not_split_a_wall() -> None:
    # At 2.4 m σ ≈ 5 cm per sample: a split test in metres would cut this wall to pieces.
    far = Wall((2.7, -2.0), (2.7, 2.0))
    for seed in range(100):
        kinds = [f.kind for f in features_of(simulate_scan([far], np.random.default_rng(seed)))]
        assert kinds == ["segment"]


def test_precise_near_points_split_at_a_shallow_corner() -> None:
    # Two walls meeting at 32° (just over the corner threshold) 0.8 m away: split every time.
    cx = 0.3 + 0.8
    t = math.radians(16.0)
    vee = [
        Wall((cx - math.sin(t), -math.cos(t)), (cx, 0.0)),
        Wall((cx, 0.0), (cx - math.sin(t), math.cos(t))),
    ]
    for seed in range(50):
        features = features_of(simulate_scan(vee, np.random.default_rng(seed)))
        assert [f.kind for f in features] == ["segment", "corner", "segment"]
