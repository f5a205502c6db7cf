"""Tests of agent.sim.world_toml: a world and its task written as world-file text, read back."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from agent.sim.taskgen import LAYOUTS, task_world
from agent.sim.world import World
from agent.sim.world_file import load_world, parse_world
from agent.sim.world_toml import world_toml
from agent.task import TASK_KINDS, Task
from tests.unit.sim.conftest import EXAMPLE_WORLDS

# Angles go through degrees in the file: an ulp of difference in about one case in seven,
# which moves a box's corners by ~1e-16 m (module docstring).
ANGLE_ATOL = 1e-15
POINT_ATOL = 1e-13


def _same_world(parsed: World, world: World) -> None:
    assert parsed.name == world.name
    np.testing.assert_allclose(parsed.vehicle_pose, world.vehicle_pose, rtol=0, atol=ANGLE_ATOL)
    assert parsed.vehicle_pose[:2] == world.vehicle_pose[:2]
    for attr in ("segments_start", "segments_end"):
        np.testing.assert_allclose(
            getattr(parsed, attr), getattr(world, attr), rtol=0, atol=POINT_ATOL
        )
    for attr in (
        "segments_reflectivity",
        "segments_obstacle",
        "circles_center",
        "circles_radius",
        "circles_reflectivity",
        "circles_obstacle",
    ):
        np.testing.assert_array_equal(getattr(parsed, attr), getattr(world, attr))
    assert [o.kind for o in parsed.obstacles] == [o.kind for o in world.obstacles]
    for p, o in zip(parsed.obstacles, world.obstacles, strict=True):
        assert (p.center, p.size, p.radius, p.reflectivity) == (
            o.center,
            o.size,
            o.radius,
            o.reflectivity,
        )
        assert p.yaw_rad == pytest.approx(o.yaw_rad, abs=ANGLE_ATOL)
    assert parsed.n_movers == world.n_movers
    for p, m in zip(parsed.movers, world.movers, strict=True):
        np.testing.assert_array_equal(p.path, m.path)
        assert (p.radius_m, p.reflectivity, p.speed_m_s) == (
            m.radius_m,
            m.reflectivity,
            m.speed_m_s,
        )


def _same_task(parsed: Task, task: Task) -> None:
    assert (parsed.kind, parsed.goal, parsed.tolerance_m, parsed.time_limit_s) == (
        task.kind,
        task.goal,
        task.tolerance_m,
        task.time_limit_s,
    )
    if task.kind == "park":
        assert parsed.goal_yaw_rad is not None and task.goal_yaw_rad is not None
        assert parsed.goal_yaw_rad == pytest.approx(task.goal_yaw_rad, abs=ANGLE_ATOL)
        assert parsed.tolerance_rad == pytest.approx(task.tolerance_rad, abs=ANGLE_ATOL)
    else:
        assert parsed.goal_yaw_rad is None
    if task.kind == "dock":
        assert parsed.dock_distance_m == task.dock_distance_m


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("kind", TASK_KINDS)
def test_task_worlds_round_trip(kind: str, layout: str) -> None:
    for i in range(3):
        world, task = task_world(np.random.default_rng([5, i]), kind, layout)  # type: ignore[arg-type]
        text = world_toml(world, task)
        parsed = parse_world(text)
        _same_world(parsed, world)
        if getattr(parsed, "task", None) is not None:
            _same_task(parsed.task, task)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("task", "keys"),
    [
        (Task("goto", (1.0, 2.0)), {"kind", "goal", "tolerance_m", "time_limit_s"}),
        (
            Task("park", (1.0, 2.0), goal_yaw_rad=0.5),
            {"kind", "goal", "goal_yaw_deg", "tolerance_m", "tolerance_deg", "time_limit_s"},
        ),
        (
            Task("dock", (1.0, 2.0), dock_distance_m=0.4),
            {"kind", "goal", "tolerance_m", "time_limit_s", "dock_distance_m"},
        ),
    ],
)
def test_task_table_has_exactly_its_keys(task: Task, keys: set[str]) -> None:
    world = World.build(walls=[(((0.0, 0.0), (1.0, 0.0)), 1.0)])
    doc = tomllib.loads(world_toml(world, task))
    assert set(doc["task"]) == keys
    assert doc["task"]["kind"] == task.kind
    assert doc["task"]["goal"] == [1.0, 2.0]
    if task.kind == "park":
        assert doc["task"]["goal_yaw_deg"] == pytest.approx(math.degrees(0.5))
        assert doc["task"]["tolerance_deg"] == pytest.approx(5.0)


def test_no_task_no_table_and_the_worlds_own_task_by_default() -> None:
    walls = [(((0.0, 0.0), (1.0, 0.0)), 1.0)]
    assert "[task]" not in world_toml(World.build(walls=walls))
    task = Task("goto", (0.5, 0.5))
    with_task = World.build(walls=walls, task=task)
    assert world_toml(with_task) == world_toml(with_task, task)
    assert "[task]" in world_toml(with_task)


def test_example_world_round_trips() -> None:
    world = load_world(EXAMPLE_WORLDS / "office.toml")
    _same_world(parse_world(world_toml(world)), world)


def test_awkward_names_round_trip() -> None:
    for name in ('a "quoted" name', "back\\slash", "tab\there", "déjà vu ☂", "del\x7fchar", ""):
        world = World.build(cylinders=[((0.0, 0.0), 0.1, 1.0)], name=name)
        assert parse_world(world_toml(world)).name == name
