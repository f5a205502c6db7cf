"""Tests of agent.sim.world_file: example and test world files, and their error messages."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.control.geometry import outline_perimeter, sweep_points
from agent.errors import WorldFileError
from agent.kinematics.vehicle import VehicleSpec
from agent.sim.footprint import outline_clearance, outline_clearances
from agent.sim.raycast import cast_rays, ray_directions
from agent.sim.world import Obstacle, World, world_from_obstacles
from agent.sim.world_file import load_world, parse_world
from agent.task import Task
from tests.unit.sim.conftest import EXAMPLE_WORLDS, TEST_WORLDS, check_single_line_error, one_ray

pytestmark = pytest.mark.filterwarnings("error")


@pytest.mark.parametrize("name", ["box_before_wall.toml", "cylinder.toml", "office.toml"])
def test_example_worlds_load(name: str) -> None:
    world = load_world(EXAMPLE_WORLDS / name)
    assert world.n_obstacles >= 2
    assert world.vehicle_pose[:2] == (0.0, 0.0)
    assert world.name
    # The vehicle sees something in every direction it faces.
    hits = cast_rays(world, np.zeros(2), ray_directions(np.linspace(-0.5, 0.5, 21)))
    assert hits.hit.all()


def test_example_worlds_geometry() -> None:
    cylinder = load_world(EXAMPLE_WORLDS / "cylinder.toml")
    assert one_ray(cylinder, (0.0, 0.0), 0.0)[0] == pytest.approx(1.1)
    office = load_world(EXAMPLE_WORLDS / "office.toml")
    assert office.vehicle_pose[2] == pytest.approx(math.radians(-20.0))  # toward the crate
    plates = [o for o in office.obstacles if o.kind == "box" and o.reflectivity == 3.0]
    assert len(plates) == 1 and plates[0].size is not None and min(plates[0].size) <= 0.05
    assert len({o.reflectivity for o in office.obstacles}) >= 4
    assert {o.kind for o in office.obstacles} == {"wall", "box", "cylinder"}


def test_defaults_are_applied() -> None:
    world = load_world(TEST_WORLDS / "minimal.toml")
    assert world.name == "minimal"  # the file's stem
    assert world.vehicle_pose == (0.0, 0.0, 0.0)
    (cyl,) = world.obstacles
    assert (cyl.kind, cyl.center, cyl.radius) == ("cylinder", (1.0, 0.0), 0.1)
    assert cyl.reflectivity == 1.0
    assert parse_world("[[box]]\ncenter = [0, 0]\nsize = [1, 2]").obstacles[0].yaw_rad == 0.0
    assert parse_world("").name == ""


def test_full_world_file() -> None:
    world = load_world(TEST_WORLDS / "full.toml")
    assert world.name == "every key"
    x, y, yaw = world.vehicle_pose
    assert (x, y) == (0.5, -0.25) and yaw == pytest.approx(math.pi / 2)
    assert [(o.kind, o.index) for o in world.obstacles] == [
        ("wall", 0),
        ("box", 0),
        ("box", 1),
        ("cylinder", 0),
    ]
    wall, box, plain_box, cyl = world.obstacles
    assert wall.points == ((3.0, -1.0), (3.0, 1.0), (2.0, 2.0)) and wall.reflectivity == 0.5
    assert box.yaw_rad == pytest.approx(math.pi / 2) and box.size == (0.4, 0.2)
    assert plain_box.reflectivity == 1.0
    assert cyl.radius == 0.25 and cyl.reflectivity == 0.3
    assert world.segments_start.shape == (2 + 4 + 4, 2)
    # The box turned by 90 degrees shows its 0.2 m side along x.
    assert one_ray(world, (0.0, 0.0), 0.0)[0] == pytest.approx(1.4)


def test_empty_world_is_valid() -> None:
    world = load_world(TEST_WORLDS / "empty.toml")
    assert world.n_obstacles == 0 and world.name == "nothing"
    assert world.segments_start.shape == (0, 2) and world.circles_center.shape == (0, 2)
    assert world.nearby((0.0, 0.0), 1.0).n_obstacles == 0


def test_parse_world_accepts_a_mapping() -> None:
    doc: dict[str, Any] = {"cylinder": [{"center": [1.0, 2.0], "radius": 0.5}]}
    world = parse_world(doc)
    assert world.circles_center.tolist() == [[1.0, 2.0]]
    with pytest.raises(WorldFileError) as info:
        parse_world({"cylinder": [{"center": [1.0, 2.0], "radius": -0.5}]})
    check_single_line_error(info.value, None, "[[cylinder]] 1: radius")


@pytest.mark.parametrize(
    ("file", "fragments"),
    [
        ("bad_syntax.toml", ["not valid TOML", "line 4"]),
        ("unknown_key.toml", ['[[box]] 2: unknown key "colour"', "center, size, yaw_deg"]),
        ("boolean_radius.toml", ["[[cylinder]] 1: radius must be", "got true"]),
    ],
)
def test_malformed_test_worlds(file: str, fragments: list[str]) -> None:
    path = TEST_WORLDS / file
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    check_single_line_error(info.value, path, *fragments)
    assert info.value.path == path


def test_missing_and_unreadable_files(tmp_path: Path) -> None:
    missing = tmp_path / "nope.toml"
    with pytest.raises(WorldFileError) as info:
        load_world(missing)
    check_single_line_error(info.value, missing, "no such file")
    with pytest.raises(WorldFileError) as info:
        load_world(tmp_path)  # a directory
    check_single_line_error(info.value, tmp_path, "not a regular file")
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"name = '\xff\xfe'\n")
    with pytest.raises(WorldFileError) as info:
        load_world(binary)
    check_single_line_error(info.value, binary, "not UTF-8")


BOX = "[[box]]\ncenter = [0, 0]\nsize = [0.4, 0.4]\n"


@pytest.mark.parametrize(
    ("text", "fragments"),
    [
        # Unknown keys and tables.
        ("foo = 1\n", ['unknown top-level key "foo"', "allowed keys: name, vehicle, wall"]),
        ("[robot]\nx = 1\n", ['unknown top-level key "robot"']),
        ("[vehicle]\nyaw = 1\n", ['[vehicle]: unknown key "yaw"; allowed keys: pose']),
        (
            "[[cylinder]]\ncenter = [0, 0]\nradius = 1\ncolor = 2\n",
            ['[[cylinder]] 1: unknown key "color"', "allowed keys: center, radius, reflectivity"],
        ),
        # Missing keys.
        ("[[cylinder]]\ncenter = [0, 0]\n", ['[[cylinder]] 1: missing key "radius"']),
        ("[[wall]]\nreflectivity = 1\n", ['[[wall]] 1: missing key "points"']),
        (BOX + "[[box]]\ncenter = [1, 1]\n", ['[[box]] 2: missing key "size"']),
        # Wrong types.
        ('[[cylinder]]\ncenter = [0, 0]\nradius = "big"\n', ["radius must be", 'got "big"']),
        ("name = 3\n", ["name must be a string, got 3"]),
        ("wall = 3\n", ["wall must be an array of tables [[wall]]"]),
        ("[box]\ncenter = [0, 0]\nsize = [1, 1]\n", ["box must be an array of tables"]),
        ("vehicle = 1\n", ["[vehicle]: must be a table, got 1"]),
        ('[[wall]]\npoints = "line"\n', ["[[wall]] 1: points must be a list of [x, y] pairs"]),
        ('[[wall]]\npoints = [[0, 0], [1, "a"]]\n', ["point 2 of points must be two finite"]),
        # Booleans are not numbers.
        ("[[box]]\ncenter = [true, 0]\nsize = [1, 1]\n", ["center must be two finite numbers"]),
        (BOX + "yaw_deg = false\n", ["[[box]] 1: yaw_deg must be a finite number, got false"]),
        (BOX + "reflectivity = true\n", ["reflectivity must be a finite positive number"]),
        # Wrong array lengths.
        ("[[cylinder]]\ncenter = [0, 0, 0]\nradius = 1\n", ["center must be two finite numbers"]),
        ("[[box]]\ncenter = [0, 0]\nsize = [1]\n", ["size must be two positive numbers, got [1]"]),
        ("[vehicle]\npose = [0, 0]\n", ["[vehicle]: pose must be three finite numbers"]),
        # Non-finite numbers.
        ("[[cylinder]]\ncenter = [0, 0]\nradius = inf\n", ["radius must be a finite positive"]),
        ("[[cylinder]]\ncenter = [nan, 0]\nradius = 1\n", ["center must be two finite numbers"]),
        (BOX + "yaw_deg = -inf\n", ["yaw_deg must be a finite number, got -inf"]),
        (BOX + "yaw_deg = 1" + "0" * 400 + "\n", ["yaw_deg must be a finite number, got 1000"]),
        ("[vehicle]\npose = [0, 0, nan]\n", ["pose must be three finite numbers", "nan"]),
        # Non-positive sizes, radii, reflectivities.
        (
            BOX + "[[box]]\ncenter = [1, 0]\nsize = [0.4, -1]\n",
            ["[[box]] 2: size must be two positive numbers, got [0.4, -1]"],
        ),
        ("[[box]]\ncenter = [0, 0]\nsize = [0, 1]\n", ["size must be two positive numbers"]),
        ("[[cylinder]]\ncenter = [0, 0]\nradius = 0\n", ["radius must be a finite positive"]),
        (BOX + "reflectivity = 0\n", ["[[box]] 1: reflectivity must be a finite positive"]),
        (
            "[[wall]]\npoints = [[0, 0], [1, 0]]\nreflectivity = -1\n",
            ["[[wall]] 1: reflectivity must be a finite positive number, got -1"],
        ),
        # Polylines.
        ("[[wall]]\npoints = [[0, 0]]\n", ["points must hold at least 2 points, got 1"]),
        ("[[wall]]\npoints = []\n", ["points must hold at least 2 points, got 0"]),
        (
            "[[wall]]\npoints = [[0, 0], [1, 0]]\n[[wall]]\npoints = [[0, 0], [1, 0], [1, 0]]\n",
            ["[[wall]] 2: zero-length segment: points 2 and 3 are both [1.0, 0.0]"],
        ),
        # Not TOML.
        ("[[box]\n", ["not valid TOML"]),
        ('name = "a\nb"\n', ["not valid TOML"]),
    ],
)
def test_world_file_errors(tmp_path: Path, text: str, fragments: list[str]) -> None:
    path = tmp_path / "w.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    check_single_line_error(info.value, path, *fragments)
    with pytest.raises(WorldFileError) as info:
        parse_world(text)
    check_single_line_error(info.value, None, *fragments)


# --------------------------------------------------------------------------------------------
# [task]
# --------------------------------------------------------------------------------------------
GOTO = '[task]\nkind = "goto"\ngoal = [6, 1]\n'
PARK = '[task]\nkind = "park"\ngoal = [6, 1]\ngoal_yaw_deg = 90\n'
DOCK = '[task]\nkind = "dock"\ngoal = [6, 1]\n'


def test_a_world_without_a_task_has_none() -> None:
    assert parse_world(BOX).task is None
    assert load_world(EXAMPLE_WORLDS / "office.toml").task is None


def test_task_defaults() -> None:
    task = parse_world(GOTO).task
    assert task == Task("goto", (6.0, 1.0))
    assert task is not None
    assert (task.tolerance_m, task.time_limit_s, task.dock_distance_m) == (0.3, 120.0, 0.5)
    assert task.tolerance_rad == pytest.approx(math.radians(5.0))
    assert parse_world(DOCK).task == Task("dock", (6.0, 1.0))


def test_task_keys_in_degrees_become_radians() -> None:
    text = PARK + "tolerance_m = 0.2\ntolerance_deg = 10\ntime_limit_s = 60.5\n"
    task = parse_world(text).task
    assert task is not None and task.kind == "park" and task.goal == (6.0, 1.0)
    assert task.goal_yaw_rad == pytest.approx(math.pi / 2)
    assert task.tolerance_rad == pytest.approx(math.radians(10.0))
    assert (task.tolerance_m, task.time_limit_s) == (0.2, 60.5)
    dock = parse_world(DOCK + "dock_distance_m = 0.75\n").task
    assert dock is not None and dock.dock_distance_m == 0.75 and dock.goal_yaw_rad is None


def test_the_task_is_kept_by_nearby_and_by_worlds_built_in_code() -> None:
    world = parse_world(BOX + PARK)
    assert world.nearby((100.0, 100.0), 1.0).task is world.task
    task = Task("goto", (1.0, 2.0))
    assert World.build(boxes=[((0, 0), (1, 1), 0.0, 1.0)], task=task).task is task
    with pytest.raises(WorldFileError, match="task: must be a Task"):
        world_from_obstacles(task="goto")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("text", "fragments"),
    [
        ("[task]\ngoal = [1, 2]\n", ['[task]: missing key "kind"']),
        ('[task]\nkind = "goto"\n', ['[task]: missing key "goal"']),
        (GOTO + "speed = 1\n", ['[task]: unknown key "speed"', "allowed keys: kind, goal"]),
        ("task = 3\n", ["[task]: must be a table, got 3"]),
        ('[task]\nkind = "fetch"\ngoal = [1, 2]\n', ['[task]: kind must be one of "goto"']),
        ("[task]\nkind = 1\ngoal = [1, 2]\n", ["[task]: kind must be one of", "got 1"]),
        ('[task]\nkind = "goto"\ngoal = [1]\n', ["[task]: goal must be two finite numbers"]),
        ('[task]\nkind = "goto"\ngoal = [1, nan]\n', ["[task]: goal must be two finite"]),
        ('[task]\nkind = "goto"\ngoal = [1, 2000]\n', ["[task]: goal must lie within 1000 m"]),
        (GOTO + "goal_yaw_deg = 90\n", ['[task]: goal_yaw_deg is for kind "park" only']),
        (DOCK + "goal_yaw_deg = 90\n", ['goal_yaw_deg is for kind "park" only, not "dock"']),
        (GOTO + "dock_distance_m = 0.5\n", ['[task]: dock_distance_m is for kind "dock" only']),
        (PARK + "dock_distance_m = 0.5\n", ['dock_distance_m is for kind "dock" only']),
        ('[task]\nkind = "park"\ngoal = [1, 2]\n', ['[task]: missing key "goal_yaw_deg"']),
        (PARK.replace("90", "nan"), ["[task]: goal_yaw_deg must be a finite number"]),
        (PARK.replace("90", "400"), ["[task]: goal_yaw_deg must be within ±360 deg"]),
        (GOTO + "tolerance_m = 0\n", ["[task]: tolerance_m must be a finite positive number"]),
        (GOTO + "tolerance_m = -0.3\n", ["[task]: tolerance_m must be a finite positive"]),
        (GOTO + 'tolerance_m = "0.3"\n', ["[task]: tolerance_m must be", 'got "0.3"']),
        (PARK + "tolerance_deg = inf\n", ["[task]: tolerance_deg must be a finite positive"]),
        (PARK + "tolerance_deg = 200\n", ["[task]: tolerance_deg must be at most 180"]),
        (GOTO + "time_limit_s = 0\n", ["[task]: time_limit_s must be a finite positive"]),
        (GOTO + "time_limit_s = true\n", ["[task]: time_limit_s must be", "got true"]),
        (DOCK + "dock_distance_m = -1\n", ["[task]: dock_distance_m must be a finite positive"]),
    ],
)
def test_task_errors(tmp_path: Path, text: str, fragments: list[str]) -> None:
    path = tmp_path / "w.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(WorldFileError) as info:
        load_world(path)
    check_single_line_error(info.value, path, *fragments)


# --------------------------------------------------------------------------------------------
# The demo world
# --------------------------------------------------------------------------------------------
DEMO = EXAMPLE_WORLDS / "demo.toml"
# The route its comments describe, and the pose docked at the plate.
DEMO_ROUTE = np.array(
    [(0.0, 0.0), (1.2, -0.8), (2.8, -0.8), (4.0, 0.3), (5.4, 0.3), (6.4, 0.5), (7.17, 0.5)]
)


def _plate(world: World) -> Obstacle:
    (plate,) = [o for o in world.obstacles if o.kind == "box" and o.reflectivity >= 2.5]
    return plate


def test_demo_world_has_a_dock_task_near_a_docking_plate() -> None:
    world = load_world(DEMO)
    assert world.name == "demo" and world.n_movers == 2
    task = world.task
    assert task is not None and task.kind == "dock" and task.dock_distance_m == 0.5
    plate = _plate(world)
    assert plate.size == (0.02, 0.4) and plate.reflectivity == 3.0 and plate.center is not None
    assert math.dist(task.goal, plate.center) < 0.1
    # About 9 m x 5 m.
    xy = np.vstack([world.segments_start, world.segments_end])
    assert np.ptp(xy, axis=0) == pytest.approx([9.0, 5.0])
    for mover in world.movers:
        assert 0.2 <= mover.radius_m <= 0.25 and 0.3 <= mover.speed_m_s <= 0.5


def test_demo_world_start_and_docking_poses_are_clear() -> None:
    world = load_world(DEMO)
    vehicle = VehicleSpec()
    start, _ = outline_clearance(world, world.vehicle_pose)
    assert start >= 0.25
    # Docked: the head's centre of scanning 0.5 m in front of the plate's face, square to it.
    plate = _plate(world)
    assert plate.center is not None and plate.size is not None
    face_x = plate.center[0] - 0.5 * plate.size[0]  # the plate faces west (-x)
    head_x = face_x - 0.5
    docked = (head_x - vehicle.head_offset_m, plate.center[1], 0.0)
    assert docked[:2] == pytest.approx(tuple(DEMO_ROUTE[-1]))
    clearance, _ = outline_clearance(world, docked)
    assert clearance >= 0.1


def _route_poses(route: np.ndarray, start_yaw: float, end_yaw: float) -> np.ndarray:
    """Poses every 1 cm along each leg, facing along it, and turning on the spot at each
    waypoint from one leg's heading to the next (every 2°)."""
    legs = np.diff(route, axis=0)
    headings = np.concatenate([[start_yaw], np.arctan2(legs[:, 1], legs[:, 0]), [end_yaw]])
    poses = []
    for i, point in enumerate(route):
        turn = headings[i + 1] - headings[i]
        yaws = headings[i] + np.linspace(0.0, 1.0, max(2, math.ceil(abs(turn) / 0.035))) * turn
        poses.append(np.column_stack([np.tile(point, (yaws.size, 1)), yaws]))
        if i < len(legs):
            s = np.linspace(0.0, 1.0, max(2, math.ceil(float(np.hypot(*legs[i])) / 0.01)))
            along = point + s[:, None] * legs[i]
            poses.append(np.column_stack([along, np.full(s.size, headings[i + 1])]))
    return np.vstack(poses)


def test_demo_route_is_passable_with_room_on_each_side() -> None:
    """Along the route (static obstacles; the movers cross it on purpose) the outline keeps
    at least 0.25 m from everything, so every gap it passes is at least 0.6 + 2·0.25 m."""
    world = load_world(DEMO)
    assert tuple(DEMO_ROUTE[0]) == world.vehicle_pose[:2]
    poses = _route_poses(DEMO_ROUTE, world.vehicle_pose[2], 0.0)
    clearance, _ = outline_clearances(world, poses)
    assert clearance.min() >= 0.25
    # The start faces the first leg, give or take 10°.
    first = math.atan2(*(DEMO_ROUTE[1] - DEMO_ROUTE[0])[::-1])
    assert abs(world.vehicle_pose[2] - first) < math.radians(10.0)


def _outline_points(poses: np.ndarray, spacing_m: float = 0.02) -> np.ndarray:
    """(n·p, 2): the vehicle's outline round its edges, every ``spacing_m``, at ``poses``."""
    outline = outline_perimeter(VehicleSpec(), spacing_m)
    return sweep_points(poses, outline).reshape(-1, 2)


def _walker_gap(mover: Any, points: np.ndarray) -> float:
    """The least distance from ``points`` to the mover's surface over its walk."""
    xy, _ = mover.states(np.linspace(0.0, mover.period_s, 1000))
    gap = np.hypot(points[:, None, 0] - xy[None, :, 0], points[:, None, 1] - xy[None, :, 1])
    return float(gap.min()) - mover.radius_m


def test_demo_movers_walk_up_to_the_route_and_never_touch_a_static_obstacle() -> None:
    """Each walker comes within 0.75 m of the vehicle's outline somewhere along the route
    (near enough that the vehicle must see it coming and give way while it may reach its
    way), turns back at least 0.2 m short of it, and keeps off every static obstacle."""
    world = load_world(DEMO)
    points = _outline_points(_route_poses(DEMO_ROUTE, world.vehicle_pose[2], 0.0)[::5])
    point = VehicleSpec(length_m=1e-9, width_m=1e-9)  # clearances of a point
    for mover in world.movers:
        xy, _ = mover.states(np.linspace(0.0, mover.period_s, 2000))
        to_static, _ = outline_clearances(world, np.column_stack([xy, np.zeros(len(xy))]),
                                          vehicle=point)  # fmt: skip
        assert to_static.min() > mover.radius_m
        assert 0.2 <= _walker_gap(mover, points) <= 0.75


def test_demo_walks_keep_clear_of_the_docking_approach() -> None:
    """From the docking line's start (0.6 m before the docked pose) to the docked pose, the
    outline keeps 0.6 m or more from every walker's surface wherever it walks, four times
    the controller's give-way margin: a walk just behind the docked pose would be a walkway
    no vehicle may dock across."""
    world = load_world(DEMO)
    docked = DEMO_ROUTE[-1]
    line = np.column_stack([np.linspace(docked[0] - 0.6, docked[0], 61), np.full(61, docked[1]),
                            np.zeros(61)])  # fmt: skip
    points = _outline_points(line)
    for mover in world.movers:
        assert _walker_gap(mover, points) >= 0.6
