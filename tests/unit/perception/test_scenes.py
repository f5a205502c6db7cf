"""The perception benchmark's targeted scene classes draw what they promise."""

from __future__ import annotations

import math

import numpy as np

from agent.sim.perception_scenes import (
    FAR_M,
    FENCE_RADIUS_M,
    FENCE_TURN_RAD,
    fence_scene,
    grazing_scene,
)


def test_fences_touch_lie_far_and_differ_in_paint() -> None:
    # Over 200 fences (fixed seed): posts 0.1-0.2 m across; gaps 0 (touching) in about half
    # (binomial σ over ~800 gaps is 1.8 %: ±10 % is generous) and at most 2 cm otherwise;
    # about half the rows far (1.5-2.4 m), some turned past 0.6 rad (posts hiding each
    # other), and some fences with posts of different reflectivities.
    rng = np.random.default_rng(5)
    gaps: list[float] = []
    far = turned = mixed = 0
    for _ in range(200):
        world = fence_scene(rng)
        c, r = world.circles_center, world.circles_radius
        assert np.all((r >= 0.95 * FENCE_RADIUS_M[0]) & (r <= 1.05 * FENCE_RADIUS_M[1]))
        gap = np.linalg.norm(np.diff(c, axis=0), axis=1) - r[:-1] - r[1:]
        gaps.extend(gap.tolist())
        middle = np.mean(c, axis=0)
        far += bool(np.hypot(*middle) >= FAR_M[0])
        along = c[-1] - c[0]
        square = math.atan2(middle[1], middle[0]) + 0.5 * math.pi
        turned += abs(math.remainder(math.atan2(along[1], along[0]) - square, math.pi)) > 0.6
        mixed += np.unique(world.circles_reflectivity).size > 1
    g = np.array(gaps)
    assert np.all(g >= -1e-9) and np.all(g <= 0.02 + 1e-9)
    assert 0.4 <= np.mean(g < 1e-9) <= 0.6
    assert 70 <= far <= 130
    assert turned >= 200 * 0.2 and FENCE_TURN_RAD > 0.6
    assert 70 <= mixed <= 130


def test_grazing_walls_are_short_oblique_and_often_far() -> None:
    # 200 walls: 0.2-0.5 m long, 20-30° between the beam to the centre and the wall, about
    # half centred 1.5-2.4 m away.
    rng = np.random.default_rng(6)
    far = 0
    for _ in range(200):
        world = grazing_scene(rng)
        a, b = world.segments_start[0], world.segments_end[0]
        length = float(np.linalg.norm(b - a))
        assert 0.2 - 1e-9 <= length <= 0.5 + 1e-9
        centre = 0.5 * (a + b)
        beam = math.atan2(centre[1], centre[0])
        wall = math.atan2(b[1] - a[1], b[0] - a[0])
        graze = abs(math.remainder(wall - beam, math.pi))
        assert math.radians(20.0) - 1e-9 <= graze <= math.radians(30.0) + 1e-9
        far += bool(np.hypot(*centre) >= FAR_M[0])
    assert 70 <= far <= 130
