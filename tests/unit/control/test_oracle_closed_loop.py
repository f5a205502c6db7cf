"""The static-world oracle's geometry: which points the true world keeps clear."""

from __future__ import annotations

import numpy as np

from agent.sim.taskgen import random_tasks
from tests.unit.control.oracle_closed_loop import SeenCells, true_clear


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


def test_seen_cells_stop_at_the_first_wall_and_vouch_open_beams_as_far_as_told() -> None:
    from agent.sim.world import World

    # One wall across x = 1 m from y = -0.5 to 0.5; nothing else.
    world = World.build(walls=[([[1.0, -0.5], [1.0, 0.5]], 0.8)])
    seen = SeenCells(world, vouch_m=1.5)
    seen.scan((0.0, 0.0), -0.05, 0.05)  # three beams into the wall
    seen.scan((0.0, 0.0), 1.5, 1.6)  # beams up the y axis, meeting nothing
    assert seen.crossed(np.array([[0.5, 0.0], [0.97, 0.0]])).all()  # short of the wall
    assert not seen.crossed(np.array([[1.2, 0.0], [2.0, 0.0]])).any()  # behind it
    assert seen.crossed(np.array([[0.0, 1.4]])).all()  # open beam, within vouch_m
    assert not seen.crossed(np.array([[0.0, 1.7], [0.0, 2.4]])).any()  # past vouch_m
    assert not seen.crossed(np.array([[-0.5, -0.5]])).any()  # never in a window
