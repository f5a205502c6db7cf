"""Tests of agent.scoring.paths: the reference path a run is scored against, the path ratio."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.scoring.paths import (
    path_length_m,
    path_ratio,
    reference_goal,
    reference_path,
    shortest_path,
    turning_radius_m,
)
from agent.sim.taskgen import task_world
from agent.sim.world import World
from agent.task import TASK_KINDS, Task

OUTLINE = ((0.0, 0.0), (8.0, 0.0), (8.0, 4.0), (0.0, 4.0), (0.0, 0.0))


def _room(**kwargs: object) -> World:
    return World.build(walls=[(OUTLINE, 1.0)], vehicle_pose=(1.0, 1.0, 0.3), **kwargs)  # type: ignore[arg-type]


def test_reference_goal_is_the_goal_or_the_docking_pose() -> None:
    world = _room(boxes=[((7.97, 2.0), (0.02, 0.4), 0.0, 3.0)])
    assert reference_goal(world, Task("goto", (3.0, 2.0))) == (3.0, 2.0)
    assert reference_goal(world, Task("park", (3.0, 2.0), goal_yaw_rad=1.0)) == (3.0, 2.0)
    # The face at x = 7.96; the head 0.5 m in front, base_link 0.3 m behind the head.
    x, y = reference_goal(world, Task("dock", (7.99, 2.03)))
    assert (x, y) == pytest.approx((7.16, 2.0))
    with pytest.raises(ValueError, match="no docking target"):
        reference_goal(_room(), Task("dock", (7.99, 2.03)))


def test_reference_path_in_an_empty_room_is_the_straight_line() -> None:
    world = _room()
    path = reference_path(world, Task("goto", (7.0, 3.0)))
    assert path.length_m == pytest.approx(math.hypot(6.0, 2.0), abs=1e-12)
    other = reference_path(world, Task("goto", (7.0, 3.0)), start_xy=(2.0, 3.0))
    assert other.length_m == pytest.approx(5.0, abs=1e-12)


def test_reference_path_squeezes_where_the_vehicle_cannot_turn() -> None:
    # A 0.8 m gap: the inradius disc (0.3 m) goes through, the turning disc (0.6 m) not.
    wall_a = ((4.0, 0.0), (4.0, 1.6))
    wall_b = ((4.0, 2.4), (4.0, 4.0))
    world = World.build(walls=[(OUTLINE, 1.0), (wall_a, 1.0), (wall_b, 1.0)])
    task = Task("goto", (7.0, 2.0))
    path = reference_path(world, task, start_xy=(1.0, 2.0))
    assert path.length_m == pytest.approx(6.0, abs=1e-12)
    assert shortest_path(world, (1.0, 2.0), (7.0, 2.0), turning_radius_m()).length_m == math.inf


def test_reference_is_no_longer_than_the_generators_path() -> None:
    # The inradius disc goes wherever the turning disc goes: a lower bound, up to the
    # 16-neighbour grid's 2.8 % (the paths are pulled straight, so far less in practice).
    for i, kind in enumerate(TASK_KINDS * 2):
        world, task = task_world(np.random.default_rng([31, i]), kind)
        ref = reference_path(world, task).length_m
        goal = reference_goal(world, task)
        turning = shortest_path(world, world.vehicle_pose[:2], goal, turning_radius_m())
        assert 0.0 < ref <= turning.length_m * 1.028
        assert ref >= math.dist(world.vehicle_pose[:2], goal) - 1e-9


def test_path_length_and_ratio_by_hand() -> None:
    driven = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 4.0], [3.0, 4.0]])
    assert path_length_m(driven) == 7.0
    assert path_length_m(np.zeros((1, 2))) == 0.0
    assert path_length_m(np.zeros((0, 2))) == 0.0
    assert path_ratio(driven, 5.0) == pytest.approx(1.4)
    with pytest.raises(ValueError, match="shortest_path_m"):
        path_ratio(driven, 0.0)
    with pytest.raises(ValueError, match="shortest_path_m"):
        path_ratio(driven, math.inf)
    with pytest.raises(ValueError, match=r"shape \(k, 2\)"):
        path_length_m(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="finite"):
        path_length_m([[0.0, 0.0], [math.nan, 1.0]])
