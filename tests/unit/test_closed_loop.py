"""The lock-step closed loop (cli.closed_loop): a bench's stage wrappers change nothing."""

from __future__ import annotations

import dataclasses
from collections import defaultdict

import numpy as np
import pytest

from agent.control.settings import ControllerSettings
from agent.runtime.stage import Stage
from agent.sim.taskgen import random_tasks
from agent.sim.world_file import parse_world
from cli.closed_loop import run_closed_loop
from tests.unit.bench_closed_loop import TimedStage


def test_stages_wrapped_for_timing_give_the_same_run() -> None:
    world, task = random_tasks(1, 0)[0]
    task = dataclasses.replace(task, time_limit_s=3.0)
    plain = run_closed_loop(world, task, seed=5)
    wall: dict[str, float] = defaultdict(float)
    cpu: dict[str, float] = defaultdict(float)
    wrapped_names: list[str] = []

    def wrap(name: str, stage: Stage) -> Stage:
        wrapped_names.append(name)
        return TimedStage(name, stage, wall, cpu)

    timed = run_closed_loop(world, task, seed=5, wrap_stage=wrap)
    assert wrapped_names == ["world", "head", "calibration", "filtering", "features",
                             "tracking", "planner", "vehicle"]  # fmt: skip
    assert set(cpu) == set(wall) == set(wrapped_names)  # every stage was called and timed
    assert all(v > 0.0 for v in wall.values())
    for field in dataclasses.fields(plain):
        if field.name == "wall_s":
            continue
        a, b = getattr(plain, field.name), getattr(timed, field.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b, field.name


def test_a_walker_into_the_vehicle_is_a_collision_with_a_mover() -> None:
    """A walker crosses the start at 0.5 m/s while the vehicle looks round on the spot: a
    collision, with a mover (and by the vehicle: it was turning)."""
    world = parse_world(
        """
        [vehicle]
        pose = [0.0, 0.0, 0.0]
        [[wall]]
        points = [[-4.0, -4.0], [8.0, -4.0], [8.0, 4.0], [-4.0, 4.0], [-4.0, -4.0]]
        [[mover]]
        radius = 0.2
        path = [[0.0, -3.5], [0.0, 3.5]]
        speed = 0.5
        [task]
        kind = "goto"
        goal = [6.0, 0.0]
        time_limit_s = 20.0
        """
    )
    assert world.task is not None
    result = run_closed_loop(world, world.task, seed=1)
    assert result.outcome == "collision" and result.collision_with == "mover"
    assert result.collision_by in ("vehicle", "mover")
    # A wall 3 cm beside the vehicle, where the worlds promise 0.42 m: its look round at the
    # start turns a corner into it. A collision with something static.
    wall = parse_world(
        """
        [vehicle]
        pose = [0.0, 0.0, 0.0]
        [[wall]]
        points = [[-4.0, 0.33], [4.0, 0.33]]
        [task]
        kind = "goto"
        goal = [3.0, -2.0]
        time_limit_s = 5.0
        """
    )
    assert wall.task is not None
    touched = run_closed_loop(wall, wall.task, seed=1)
    assert (touched.outcome, touched.collision_with) == ("collision", "static")


_CELL, _ORIGIN = 0.05, np.array([-2.0, -2.0])


def _known_below(x_m: float) -> np.ndarray:
    """An (80, 80) known space of 5 cm cells from (-2, -2): clear where x < ``x_m``, unknown
    (``BAND``) beyond."""
    from agent.control.clearance import BAND, CLEAR

    state = np.full((80, 80), BAND, dtype=np.uint8)
    xs = _ORIGIN[0] + (np.arange(80) + 0.5) * _CELL
    state[:, xs < x_m] = CLEAR
    return state


def test_known_ahead_is_the_share_of_the_swept_cells_known_clear() -> None:
    from agent.control.clearance import CLEAR
    from cli.closed_loop import known_ahead

    cell, origin = _CELL, _ORIGIN
    # Known clear: everything with x < 0.6 (the outline at the origin reaches x = 0.4).
    state = _known_below(0.6)
    # Driving straight ahead at 0.5 m/s for 2 s: the outline sweeps x from 0.4 to 1.4.
    odometry = [(0.1 * k, 0.05 * k, 0.0, 0.0) for k in range(30)]
    share = known_ahead([(0.0, origin, cell, state)], odometry)
    assert share is not None
    assert 0.15 < share < 0.25  # 0.2 m of the 1 m swept beyond the outline was known clear
    state[:] = CLEAR
    assert known_ahead([(0.0, origin, cell, state)], odometry) == 1.0
    # Standing still: no sample.
    still = [(0.1 * k, 0.0, 0.0, 0.0) for k in range(30)]
    assert known_ahead([(0.0, origin, cell, state)], still) is None


def test_known_way_is_how_far_it_drove_on_what_it_knew() -> None:
    from agent.control.clearance import CLEAR
    from cli.closed_loop import known_way

    cell, origin = _CELL, _ORIGIN
    state = _known_below(0.8)  # known clear to 0.8 m: the front (0.4 m ahead) may go 0.4 m
    odometry = [(0.1 * k, 0.05 * k, 0.0, 0.0) for k in range(40)]  # 1.95 m straight on
    way = known_way([(0.0, origin, cell, state)], odometry)
    assert way is not None and 0.35 <= way <= 0.4
    state[:] = CLEAR
    assert known_way([(0.0, origin, cell, state)], odometry) == pytest.approx(1.0)
    # Not 1 m driven after the sample: left out.
    assert known_way([(3.0, origin, cell, state)], odometry) is None


def test_progress_is_the_share_of_the_reference_path_made() -> None:
    from agent.scoring.paths import reference_goal, reference_path
    from cli.closed_loop import VEHICLE, progress

    world, task = random_tasks(1, 0)[0]
    start = (float(world.vehicle_pose[0]), float(world.vehicle_pose[1]))
    goal = reference_goal(world, task, VEHICLE)
    assert progress(world, task, start) == pytest.approx(0.0)
    assert progress(world, task, goal) == pytest.approx(1.0)
    # Half way along the reference path (within a cell of the grid it is found on).
    path = reference_path(world, task).waypoints
    steps = np.hypot(*np.diff(path, axis=0).T)
    along = np.concatenate([[0.0], np.cumsum(steps)])
    half = [np.interp(0.5 * along[-1], along, path[:, i]) for i in (0, 1)]
    assert progress(world, task, (float(half[0]), float(half[1]))) == pytest.approx(0.5, abs=0.05)
    # From inside an obstacle no path starts: the straight distance to the goal stands in.
    inside = tuple(float(v) for v in world.circles_center[0]) if len(world.circles_center) else None
    if inside is not None:
        straight = float(np.hypot(inside[0] - goal[0], inside[1] - goal[1]))
        expected = 1.0 - straight / reference_path(world, task).length_m
        assert progress(world, task, inside) == pytest.approx(expected)


def test_the_known_way_of_a_creeping_vehicle_is_scored_on_thinned_poses() -> None:
    from cli.closed_loop import _outline_motion, _thinned, known_ahead, known_way

    cell, origin = _CELL, _ORIGIN
    state = _known_below(0.8)
    # 1 mm a pose (odometry at 20 Hz while creeping at 2 cm/s), turning slowly on the way.
    poses = [(0.05 * k, 0.001 * k, 0.0, 1e-4 * k) for k in range(1500)]
    motion = _outline_motion(np.array(poses)[:, 1:])
    kept = _thinned(motion, 0.5 * cell)
    assert kept[0] == 0 and kept[-1] == len(poses) - 1
    assert np.diff(motion[kept]).max() <= 0.5 * cell + 0.002  # no more than a step apart
    assert 60 < kept.size < 120  # not 1,500
    way = known_way([(0.0, origin, cell, state)], poses)
    assert way is not None and 0.3 <= way <= 0.4
    # 4 cm in the 2 s after the sample: too little to score what was known ahead.
    assert known_ahead([(0.0, origin, cell, state)], poses) is None


def test_the_time_standing_is_kept_by_the_controller_s_reason() -> None:
    # The start: the vehicle stands while the head looks round (look_stand_s), then goes.
    world, task = random_tasks(1, 0)[0]
    task = dataclasses.replace(task, time_limit_s=4.0)
    result = run_closed_loop(world, task, seed=5)
    looking = ControllerSettings().look_stand_s
    assert result.standing_s["looking"] == pytest.approx(looking, abs=0.5)
    assert sum(result.standing_s.values()) <= result.time_s + 1e-9
