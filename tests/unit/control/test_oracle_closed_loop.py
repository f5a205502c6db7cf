"""The static-world oracle's geometry: which points the true world keeps clear."""

from __future__ import annotations

import numpy as np

from agent.sim.taskgen import random_tasks
from tests.unit.control.oracle_closed_loop import true_clear


def test_the_true_world_is_clear_away_from_its_walls_and_cylinders() -> None:
    ((world, _),) = random_tasks(1, 0)
    start = np.asarray(world.segments_start)
    end = np.asarray(world.segments_end)
    mid = 0.5 * (start + end)
    assert not true_clear(world, mid, 0.01).any()  # on every wall
    if len(world.circles_center):
        rim = world.circles_center + np.c_[world.circles_radius + 0.005, 0.0 * world.circles_radius]
        assert not true_clear(world, rim, 0.01).any()  # 5 mm off every cylinder
    # The vehicle's start: the generator keeps its turning circle clear.
    assert true_clear(world, np.asarray(world.vehicle_pose[:2])[None], 0.5).all()
    # Across a wall's middle, 10 cm out on its normal: clear at a 5 cm margin.
    d = end - start
    normal = np.c_[-d[:, 1], d[:, 0]] / np.hypot(d[:, 0], d[:, 1])[:, None]
    off = true_clear(world, mid + 0.1 * normal, 0.05) | true_clear(world, mid - 0.1 * normal, 0.05)
    assert off.mean() > 0.9  # a few walls meet others within 10 cm of their middle
