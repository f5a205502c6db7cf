"""Tests of agent.sim.taskgen: random worlds with solvable tasks, reproducible run by run."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from agent.kinematics.vehicle import VehicleSpec
from agent.sim.footprint import outline_clearance
from agent.sim.movers import MOVER_GAP_M
from agent.sim.paths import CELL_M, clearance_grid, path_field, point_clearance, turning_radius_m
from agent.sim.taskgen import (
    DOCK_DISTANCE_M,
    GOAL_CLEARANCE_M,
    LAYOUTS,
    MAX_PRIMITIVES,
    MOVER_CLEARANCE_M,
    PARTITION_THICKNESS_M,
    PATH_LENGTH_M,
    START_CLEARANCE_M,
    random_tasks,
    task_world,
    time_limit_s,
)
from agent.sim.world import World
from agent.sim.world_toml import world_toml
from agent.sim.worldgen import _segment_distance
from agent.task import TASK_KINDS, Task
from tests.unit.sim.conftest import closest_bodies

SPEC = VehicleSpec()
BRIGHT = 2.5  # the agent's docking threshold


def _plate(world: World) -> tuple[tuple[float, float], tuple[float, float], float, float]:
    """The one docking plate's centre, size, yaw and reflectivity."""
    plates = [o for o in world.obstacles if o.reflectivity >= BRIGHT]
    assert len(plates) == 1
    p = plates[0]
    assert p.kind == "box" and p.center is not None and p.size is not None
    return p.center, p.size, p.yaw_rad, p.reflectivity


def _wall_gap(world: World, xy: tuple[float, float]) -> tuple[float, np.ndarray]:
    """Distance from ``xy`` to the nearest wall segment, and the nearest point on it."""
    walls = [o.id for o in world.obstacles if o.kind == "wall"]
    on_wall = np.isin(world.segments_obstacle, walls)
    a, b = world.segments_start[on_wall], world.segments_end[on_wall]
    e = b - a
    t = np.clip(np.einsum("ij,ij->i", np.asarray(xy) - a, e) / np.einsum("ij,ij->i", e, e), 0, 1)
    nearest = a + t[:, None] * e
    d = np.hypot(*(nearest - xy).T)
    k = int(np.argmin(d))
    return float(d[k]), nearest[k]


def _goal_pose(world: World, task: Task) -> tuple[float, float, float]:
    """Where base_link ends the task: for dock, square to the plate's face on the room side
    (the side of its wall the plate is on)."""
    if task.kind != "dock":
        yaw = task.goal_yaw_rad if task.goal_yaw_rad is not None else 0.0
        return task.goal[0], task.goal[1], yaw
    centre, size, _, _ = _plate(world)
    _, on_wall = _wall_gap(world, centre)
    n = (np.asarray(centre) - on_wall) / math.dist(centre, on_wall)
    base = np.asarray(centre) + (0.5 * size[0] + DOCK_DISTANCE_M + SPEC.head_offset_m) * n
    return float(base[0]), float(base[1]), math.atan2(-n[1], -n[0])


def _check(world: World, task: Task) -> None:
    """Everything the generator promises of one world and task."""
    assert world.task == task
    start = np.array(world.vehicle_pose[:2])
    # Small enough to simulate fast, and reflectivities in their bands.
    assert world.segments_start.shape[0] + world.circles_radius.size <= MAX_PRIMITIVES
    every = np.concatenate([world.segments_start, world.segments_end])
    assert np.all(every.max(axis=0) - every.min(axis=0) <= 14.0 + 1e-9)
    dim = [o for o in world.obstacles if o.reflectivity < BRIGHT]
    assert all(0.3 <= o.reflectivity <= 2.0 for o in dim)
    assert all(0.3 <= m.reflectivity <= 2.0 for m in world.movers)
    if task.kind == "dock":
        centre, size, _, refl = _plate(world)
        assert size[0] == pytest.approx(0.02) and 0.3 <= size[1] <= 0.5
        assert 3.0 <= refl <= 5.0
        assert math.dist(task.goal, centre) <= 0.03 * math.sqrt(2) + 1e-12
        assert task.dock_distance_m == DOCK_DISTANCE_M
        # 1-2 cm of air between the plate's back and the wall: its centre 2-3 cm off.
        assert 0.02 - 1e-9 <= _wall_gap(world, centre)[0] <= 0.03 + 1e-9
    else:
        assert len(dim) == len(world.obstacles)
    goal = _goal_pose(world, task)
    # The start's circumcircle clear by 0.42 m (the ring the sensor cannot see from there),
    # the goal's by 0.15 m: the outline at any heading clear by that much.
    assert outline_clearance(world, world.vehicle_pose)[0] >= START_CLEARANCE_M
    assert outline_clearance(world, goal)[0] >= GOAL_CLEARANCE_M
    assert point_clearance(world, [start])[0] >= SPEC.circumradius_m + START_CLEARANCE_M
    assert point_clearance(world, [goal[:2]])[0] >= SPEC.circumradius_m + GOAL_CLEARANCE_M
    # Solvable: the path on which the vehicle can turn anywhere, 5-12 m, on the generator's
    # own grid (pad 0.5 m), and truly clear of the circumcircle all along.
    grid = clearance_grid(world, CELL_M, pad_m=0.5)
    path = path_field(grid, start, turning_radius_m(SPEC), limit_m=12.5).path_to(goal[:2])
    assert PATH_LENGTH_M[0] <= path.length_m <= PATH_LENGTH_M[1]
    steps = np.linspace(0.0, 1.0, 40)[:, None, None]
    a, b = path.waypoints[:-1], path.waypoints[1:]
    assert point_clearance(world, (a + steps * (b - a)).reshape(-1, 2)).min() >= (
        SPEC.circumradius_m
    )
    assert task.time_limit_s == time_limit_s(path.length_m)
    # Facing the first leg to within 45 degrees.
    first = path.waypoints[1] - path.waypoints[0]
    off = math.remainder(world.vehicle_pose[2] - math.atan2(first[1], first[0]), 2 * math.pi)
    assert abs(off) <= math.pi / 4 + 1e-12
    # Movers: 0-3, in their ranges, never near the start or the goal pose.
    assert len(world.movers) <= 3
    for m in world.movers:
        assert 0.15 <= m.radius_m <= 0.3 and 0.2 <= m.speed_m_s <= 0.8
        assert 1.0 - 1e-9 <= m.length_m <= 5.0 + 1e-9
        keep = SPEC.circumradius_m + MOVER_CLEARANCE_M + m.radius_m
        assert _segment_distance(np.array([start, goal[:2]]), *m.path).min() >= keep - 1e-9
    # ... nor through one another while the task lasts (5 ms steps, 2 cm of slack).
    assert closest_bodies(world.movers, task.time_limit_s) >= MOVER_GAP_M - 0.02


@pytest.mark.parametrize("first", [0, 25])  # two halves of 50, to share among workers
@pytest.mark.parametrize("kind", TASK_KINDS)
def test_fifty_tasks_of_each_kind_are_solvable(kind: str, first: int) -> None:
    for i in range(first, first + 25):
        layout = LAYOUTS[i % 2]
        world, task = task_world(np.random.default_rng([17, i]), kind, layout)  # type: ignore[arg-type]
        assert task.kind == kind
        assert world.name.startswith(f"{layout} {kind}")
        _check(world, task)


def test_a_doorway_s_edges_are_the_partition_s_end_faces() -> None:
    """Office worlds: along the line of a doorway's partition, each of the doorway's edges
    has a face PARTITION_THICKNESS_M across (seen end-on, a wall is not nothing)."""
    from agent.sim.raycast import cast_rays

    checked = 0
    for seed in range(12):
        world, _task = task_world(np.random.default_rng(seed), layout="office")
        a, b = world.segments_start, world.segments_end
        across = (np.abs(a[:, 0] - b[:, 0]) < 1e-9) & (
            np.abs(np.abs(a[:, 1] - b[:, 1]) - PARTITION_THICKNESS_M) < 1e-9
        )
        for k in np.flatnonzero(across):
            x, y = float(a[k, 0]), 0.5 * float(a[k, 1] + b[k, 1])
            # Cast along the partition's line from 0.5 m each side: one side is the doorway,
            # and from there the edge's face is hit at 0.5 m.
            for side in (-1.0, 1.0):
                hits = cast_rays(
                    world, np.array([x + 0.5 * side, y]), np.array([[-side, 0.0]]),
                    max_range_m=1.0,
                )  # fmt: skip
                if hits.hit[0] and abs(float(hits.distance_m[0]) - 0.5) < 1e-6:
                    checked += 1
    assert checked >= 24  # 2-3 doorways a side, two edges each, over 12 worlds


def test_same_generator_state_same_world() -> None:
    for seed in range(4):
        a = task_world(np.random.default_rng(seed))
        b = task_world(np.random.default_rng(seed))
        assert world_toml(*a) == world_toml(*b)
        assert a[1] == b[1]
    c = task_world(np.random.default_rng(99))
    assert world_toml(*c) != world_toml(*task_world(np.random.default_rng(98)))


def test_runs_are_independent_of_the_list_they_are_in() -> None:
    # Run i depends on (seed, i) only: a shard, or a longer list, holds the same worlds.
    runs = random_tasks(6, 7)
    assert [world_toml(*r) for r in random_tasks(3, 7)] == [world_toml(*r) for r in runs[:3]]
    for i in (0, 4, 5):
        assert world_toml(*task_world(np.random.default_rng([7, i]))) == world_toml(*runs[i])
    assert world_toml(*random_tasks(1, 8)[0]) != world_toml(*runs[0])
    assert random_tasks(0, 7) == []


def test_kinds_and_layouts_are_drawn_uniformly() -> None:
    # 30 runs: each of 3 kinds expected 10 times, each layout 15, each mover count (0-3,
    # less the dropped walks) several times. The bounds are far in the tails
    # (P(Binomial(30, 1/3) <= 3) = 0.003, P(Binomial(30, 1/2) <= 7) = 0.003); the seed is
    # fixed, so the test is repeatable, and it fails if a kind or layout never comes.
    runs = random_tasks(30, 3)
    kinds = Counter(t.kind for _, t in runs)
    layouts = Counter(w.name.split()[0] for w, _ in runs)
    assert set(kinds) == set(TASK_KINDS) and min(kinds.values()) > 3
    assert set(layouts) == set(LAYOUTS) and min(layouts.values()) > 7
    assert Counter(len(w.movers) for w, _ in runs).keys() == {0, 1, 2, 3}


def test_bad_arguments_are_refused() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="kind must be one of"):
        task_world(rng, "fly")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="layout must be one of"):
        task_world(rng, layout="maze")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="n must be >= 0"):
        random_tasks(-1, 0)
    with pytest.raises(ValueError, match="seed must be >= 0"):
        random_tasks(1, -3)


def test_gives_up_with_a_clear_error() -> None:
    # A vehicle 4 m across finds no place to start in any world.
    huge = VehicleSpec(length_m=4.0, width_m=4.0)
    with pytest.raises(ValueError, match="no solvable goto task in 30 office worlds"):
        task_world(np.random.default_rng(0), "goto", "office", vehicle=huge)
