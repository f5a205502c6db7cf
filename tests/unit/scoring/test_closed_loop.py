"""Tests of agent.scoring.closed_loop: docking face and error, success, score, Wilson interval."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.scoring.closed_loop import (
    dock_error,
    dock_pose,
    docking_face,
    normalised_score,
    task_success,
    wilson_interval,
)
from agent.sim.footprint import outline_clearance
from agent.sim.paths import point_clearance
from agent.sim.taskgen import task_world
from agent.sim.world import World
from agent.task import Task

# A plate on the east wall of a room: its face toward the room at x = 4.96, from y = 0.1 to
# 0.5; docked, the head's centre (0.3 m ahead of base_link) is at (4.46, 0.3).
FACE = np.array([[4.96, 0.1], [4.96, 0.5]])
NORMAL = np.array([-1.0, 0.0])
DOCKED = (4.16, 0.3, 0.0)


def _room(*plates: tuple[tuple[float, float], tuple[float, float], float, float]) -> World:
    outline = ((-1.0, -2.0), (5.0, -2.0), (5.0, 2.5), (-1.0, 2.5), (-1.0, -2.0))
    return World.build(
        walls=[(outline, 0.9)],
        boxes=[((2.2, -0.9), (0.5, 0.4), 0.5, 0.8), *plates],
        cylinders=[((1.5, 1.2), 0.15, 0.9)],
    )


EAST_PLATE = ((4.97, 0.3), (0.02, 0.4), 0.0, 3.0)
DOCK = Task("dock", (4.99, 0.28), tolerance_m=0.1)


# ------------------------------------------------------------------------------ dock error
def test_dock_error_is_zero_when_docked() -> None:
    assert dock_error(DOCKED, FACE, NORMAL, 0.5, 0.3) == pytest.approx((0.0, 0.0), abs=1e-9)


def test_dock_error_by_hand() -> None:
    # 1 cm to the left: 10 mm, square on.
    assert dock_error((4.16, 0.31, 0.0), FACE, NORMAL, 0.5, 0.3) == pytest.approx((10.0, 0.0))
    # 3 cm short and 4 cm right: 50 mm.
    assert dock_error((4.13, 0.26, 0.0), FACE, NORMAL, 0.5, 0.3) == pytest.approx((50.0, 0.0))
    # Turned 3 degrees about base_link: the head swings on a 0.3 m arm.
    a = math.radians(3.0)
    head = np.array([4.16 + 0.3 * math.cos(a), 0.3 + 0.3 * math.sin(a)])
    expected_mm = 1000.0 * math.dist(head, (4.46, 0.3))
    assert dock_error((4.16, 0.3, a), FACE, NORMAL, 0.5, 0.3) == pytest.approx((expected_mm, 3.0))
    # Headings wrap; the angle is unsigned; the normal need not be a unit vector.
    got = dock_error((4.16, 0.3, 2 * math.pi - a), FACE, 7.0 * NORMAL, 0.5, 0.3)
    assert got == pytest.approx((expected_mm, 3.0))
    # Facing away: 180 degrees.
    assert dock_error((4.76, 0.3, math.pi), FACE, NORMAL, 0.5, 0.3)[1] == pytest.approx(180.0)


def test_dock_pose_is_where_the_error_vanishes() -> None:
    pose = dock_pose(FACE, NORMAL, 0.5, 0.3)
    assert pose == pytest.approx(DOCKED)
    # A plate on a north wall, facing south.
    face = np.array([[1.0, 2.46], [1.4, 2.46]])
    x, y, yaw = dock_pose(face, (0.0, -1.0), 0.5, 0.3)
    assert (x, y, yaw) == pytest.approx((1.2, 1.66, math.pi / 2))
    assert dock_error((x, y, yaw), face, (0.0, -1.0), 0.5, 0.3) == pytest.approx((0, 0), abs=1e-9)


@pytest.mark.parametrize(
    ("pose", "face", "normal", "message"),
    [
        ((1.0, 2.0), FACE, NORMAL, "true_pose"),
        ((1.0, 2.0, math.nan), FACE, NORMAL, "true_pose"),
        (DOCKED, FACE[0], NORMAL, "face"),
        (DOCKED, FACE, (0.0, 0.0), "normal"),
        (DOCKED, FACE, (0.0, 1.0, 0.0), "normal"),
    ],
)
def test_dock_error_refuses_bad_input(
    pose: tuple[float, ...], face: np.ndarray, normal: tuple[float, ...], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        dock_error(pose, face, normal, 0.5, 0.3)


# ---------------------------------------------------------------------------- docking face
@pytest.mark.parametrize("yaw", [0.0, math.pi, -math.pi])
def test_docking_face_is_the_plates_room_side(yaw: float) -> None:
    world = _room(((4.97, 0.3), (0.02, 0.4), yaw, 3.0))
    face = docking_face(world, DOCK)
    np.testing.assert_allclose(sorted(face.ends[:, 1]), [0.1, 0.5], atol=1e-12)
    np.testing.assert_allclose(face.ends[:, 0], [4.96, 4.96], atol=1e-12)
    np.testing.assert_allclose(face.normal, NORMAL, atol=1e-12)
    assert world.obstacles[face.obstacle].reflectivity == 3.0


def test_docking_face_on_a_turned_wall_and_nearest_the_goal() -> None:
    # Two plates: one on the east wall, one on the north wall (turned 90 degrees).
    north = ((1.2, 2.47), (0.02, 0.4), math.pi / 2, 4.0)
    world = _room(EAST_PLATE, north)
    face = docking_face(world, Task("dock", (1.25, 2.4)))
    np.testing.assert_allclose(face.normal, (0.0, -1.0), atol=1e-12)
    np.testing.assert_allclose(face.centre, (1.2, 2.46), atol=1e-12)
    assert docking_face(world, DOCK).normal == pytest.approx(NORMAL)


def test_no_docking_target_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="no docking target"):
        docking_face(_room(), DOCK)


def test_docking_face_finds_the_generators_plates() -> None:
    # The docking pose from the face is clear, and the goal (the plate +- 3 cm) is by it.
    for i in range(6):
        world, task = task_world(np.random.default_rng([23, i]), "dock")
        face = docking_face(world, task)
        pose = dock_pose(face.ends, face.normal, task.dock_distance_m, 0.3)
        assert outline_clearance(world, pose)[0] >= 0.15
        assert point_clearance(world, pose[:2])[0] >= 0.65
        assert math.dist(face.centre, task.goal) <= 0.01 + 0.03 * math.sqrt(2)
        assert task_success(task, pose, world)


# --------------------------------------------------------------------------------- success
def test_goto_success_is_within_tolerance() -> None:
    task = Task("goto", (2.0, 1.0), tolerance_m=0.3)
    assert task_success(task, (2.0, 1.0, 2.0))
    assert task_success(task, (2.0, 1.29, -3.0))  # any heading
    assert not task_success(task, (2.0, 1.31, 0.0))
    assert not task_success(task, (2.25, 1.25, 0.0))  # 0.354 m off


def test_park_success_needs_the_heading_too() -> None:
    task = Task("park", (2.0, 1.0), goal_yaw_rad=math.pi, tolerance_rad=math.radians(5.0))
    assert task_success(task, (2.1, 1.0, math.pi))
    assert task_success(task, (2.1, 1.0, -math.pi + math.radians(4.9)))  # across the wrap
    assert not task_success(task, (2.1, 1.0, -math.pi + math.radians(5.1)))
    assert not task_success(task, (2.4, 1.0, math.pi))


def test_dock_success_is_position_and_five_degrees() -> None:
    world = _room(EAST_PLATE)
    assert task_success(DOCK, DOCKED, world)
    assert task_success(DOCK, (4.16, 0.39, 0.0), world)  # 90 mm
    assert not task_success(DOCK, (4.16, 0.41, 0.0), world)  # 110 mm, tolerance 100 mm
    # Turn about the head's centre, so that only the heading is off.
    for deg, ok in ((4.9, True), (5.1, False)):
        a = math.radians(deg)
        base = (4.46 - 0.3 * math.cos(a), 0.3 - 0.3 * math.sin(a), a)
        assert task_success(DOCK, base, world) is ok
    with pytest.raises(ValueError, match="needs the world"):
        task_success(DOCK, DOCKED)


# ----------------------------------------------------------------------------------- score
@pytest.mark.parametrize("path_m", [1.0, 5.0, 12.3])
@pytest.mark.parametrize("ratio", [0.0, 0.5, 1.0, 2.0, 3.0, 5.5, 8.0, 9.0, 40.0])
def test_score_is_the_formula(path_m: float, ratio: float) -> None:
    t_ref = path_m / 0.5
    t = ratio * t_ref
    expected = t_ref / min(max(t, 2 * t_ref), 8 * t_ref)
    assert normalised_score(True, t, path_m) == pytest.approx(expected)
    assert normalised_score(False, t, path_m) == 0.0


def test_score_by_hand() -> None:
    # 5 m: T_ref = 10 s.
    assert normalised_score(True, 15.0, 5.0) == 0.5  # faster than 2 T_ref: clipped
    assert normalised_score(True, 20.0, 5.0) == 0.5
    assert normalised_score(True, 40.0, 5.0) == 0.25
    assert normalised_score(True, 80.0, 5.0) == 0.125
    assert normalised_score(True, 500.0, 5.0) == 0.125
    assert normalised_score(True, 40.0, 5.0, speed_m_s=0.25) == 0.5  # T_ref = 20 s


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((True, -1.0, 5.0), "time_s"),
        ((True, math.inf, 5.0), "time_s"),
        ((True, 10.0, 0.0), "shortest_path_m"),
        ((True, 10.0, math.inf), "shortest_path_m"),
        ((True, 10.0, 5.0, 0.0), "speed_m_s"),
    ],
)
def test_score_refuses_bad_input(args: tuple[float, ...], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        normalised_score(*args)  # type: ignore[arg-type]


# ------------------------------------------------------------------------ Wilson interval
def _wilson(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson's score interval written out."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return centre - half, centre + half


@pytest.mark.parametrize(("k", "n"), [(0, 10), (5, 10), (10, 10), (37, 50), (1, 1)])
def test_wilson_interval_by_formula(k: int, n: int) -> None:
    lo, hi = wilson_interval(k, n)
    assert (lo, hi) == pytest.approx(_wilson(k, n), abs=1e-12)
    assert 0.0 <= lo <= k / n <= hi <= 1.0


def test_wilson_interval_by_hand_and_at_the_edges() -> None:
    assert wilson_interval(5, 10) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    assert wilson_interval(0, 10)[0] == 0.0
    narrow = wilson_interval(5, 10, 0.5)
    assert narrow[0] > 0.2366 and narrow[1] < 0.7634
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    for bad in ((11, 10), (-1, 10), (1, -1)):
        with pytest.raises(ValueError, match="successes"):
            wilson_interval(*bad)
    with pytest.raises(ValueError, match="confidence"):
        wilson_interval(1, 2, 1.0)
