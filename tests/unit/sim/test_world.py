"""Tests of agent.sim.world: worlds built in code, their arrays, and culling."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.errors import WorldFileError
from agent.sim.raycast import cast_rays, ray_directions
from agent.sim.world import World, world_from_obstacles
from tests.unit.sim.conftest import check_single_line_error, random_world

pytestmark = pytest.mark.filterwarnings("error")


def test_world_from_obstacles_layout() -> None:
    world = World.build(
        walls=[(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), 0.5)],
        boxes=[((2.0, 0.0), (1.0, 0.5), 0.0, 2.0)],
        cylinders=[((5.0, 5.0), 0.2, 3.0)],
        vehicle_pose=(1.0, 2.0, 0.5),
        name="built",
    )
    assert world.n_obstacles == 3 and world.name == "built"
    assert [(o.kind, o.index, o.id) for o in world.obstacles] == [
        ("wall", 0, 0),
        ("box", 0, 1),
        ("cylinder", 0, 2),
    ]
    assert world.segments_start.shape == (6, 2)  # 2 wall pieces + 4 box faces
    assert world.segments_obstacle.tolist() == [0, 0, 1, 1, 1, 1]
    assert world.segments_reflectivity.tolist() == [0.5, 0.5, 2.0, 2.0, 2.0, 2.0]
    assert world.circles_obstacle.tolist() == [2]
    box = world.obstacles[1]
    assert box.points == ((2.5, -0.25), (2.5, 0.25), (1.5, 0.25), (1.5, -0.25))
    assert world.vehicle_pose == (1.0, 2.0, 0.5)
    for arr in (
        world.segments_start,
        world.segments_end,
        world.segments_reflectivity,
        world.segments_obstacle,
        world.circles_center,
        world.circles_radius,
        world.circles_reflectivity,
        world.circles_obstacle,
    ):
        assert not arr.flags.writeable
    with pytest.raises(ValueError):
        world.segments_start[0, 0] = 9.0


def test_world_from_obstacles_accepts_numpy_values() -> None:
    world = world_from_obstacles(
        walls=[([np.array([0.0, 0.0]), np.array([1.0, 0.0])], np.float64(0.5))],
        boxes=[(np.array([2.0, 0.0]), np.array([1.0, 1.0]), np.float64(0.1), 1)],
        cylinders=[(np.array([3.0, 0.0]), np.float64(0.25), 2)],
        vehicle_pose=np.array([1.0, 2.0, 3.0]),
    )
    assert world.n_obstacles == 3 and world.vehicle_pose == (1.0, 2.0, 3.0)
    assert world.obstacles[2].radius == 0.25


def test_world_copies_its_arrays() -> None:
    start = np.array([[0.0, 0.0]])
    world = World(
        segments_start=start,
        segments_end=np.array([[1.0, 0.0]]),
        segments_reflectivity=np.array([1.0]),
        segments_obstacle=np.array([0]),
        circles_center=np.zeros((0, 2)),
        circles_radius=np.zeros(0),
        circles_reflectivity=np.zeros(0),
        circles_obstacle=np.zeros(0, dtype=np.int64),
        obstacles=world_from_obstacles(walls=[([(0.0, 0.0), (1.0, 0.0)], 1.0)]).obstacles,
    )
    start[0, 0] = 5.0
    assert world.segments_start[0, 0] == 0.0
    assert start.flags.writeable


def test_world_from_obstacles_checks_like_a_file() -> None:
    with pytest.raises(WorldFileError) as info:
        world_from_obstacles(boxes=[((0.0, 0.0), (0.4, 0.4), 0.0, 1.0), ((0, 0), (0.4, -1), 0, 1)])
    check_single_line_error(info.value, None, "[[box]] 2: size must be two positive numbers")
    with pytest.raises(WorldFileError):
        world_from_obstacles(cylinders=[((0.0, 0.0), True, 1.0)])
    with pytest.raises(WorldFileError):
        world_from_obstacles(walls=[([(0.0, 0.0)], 1.0)])


def test_nearby_keeps_and_drops_the_right_obstacles() -> None:
    world = world_from_obstacles(
        walls=[([(10.0, -1.0), (10.0, 1.0)], 1.0)],  # bounding circle (10, 0), r 1: gap 9
        boxes=[((0.0, 3.0), (1.0, 1.0), 0.3, 1.0)],  # r sqrt(0.5): gap 2.29
        cylinders=[((1.0, 0.0), 0.1, 1.0), ((5.0, 0.0), 0.5, 1.0)],  # gaps 0.9 and 4.5
        vehicle_pose=(0.0, 0.0, 1.0),
        name="n",
    )
    near = world.nearby((0.0, 0.0), 2.0)
    assert [o.id for o in near.obstacles] == [2]
    assert near.segments_start.shape == (0, 2)
    assert near.circles_obstacle.tolist() == [2]
    assert near.vehicle_pose == world.vehicle_pose and near.name == "n"

    wider = world.nearby(np.array([0.0, 0.0]), 2.5)
    assert [o.id for o in wider.obstacles] == [1, 2]
    assert set(wider.segments_obstacle.tolist()) == {1}
    assert wider.segments_start.shape == (4, 2)

    assert [o.id for o in world.nearby((8.0, 0.0), 1.5).obstacles] == [0]  # the wall: gap 1
    assert [o.id for o in world.nearby((8.0, 0.0), 2.6).obstacles] == [0, 3]  # cylinder: 2.5
    assert world.nearby((0.0, 0.0), math.inf).n_obstacles == 4
    assert world.nearby((50.0, 50.0), 1.0).n_obstacles == 0


def test_nearby_world_casts_like_the_full_one() -> None:
    rng = np.random.default_rng(11)
    world = random_world(rng, 6, 20, 10)
    center, radius = np.array([0.5, -0.5]), 3.0
    near = world.nearby(center, radius)
    assert 0 < near.n_obstacles < world.n_obstacles
    directions = ray_directions(np.linspace(-math.pi, math.pi, 720, endpoint=False))
    full = cast_rays(world, center, directions, max_range_m=radius)
    culled = cast_rays(near, center, directions, max_range_m=radius)
    np.testing.assert_array_equal(full.distance_m, culled.distance_m)
    np.testing.assert_array_equal(full.obstacle, culled.obstacle)
