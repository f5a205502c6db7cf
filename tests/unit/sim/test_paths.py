"""Tests of agent.sim.paths: the clearance grid, Dijkstra, and paths pulled straight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.kinematics.vehicle import VehicleSpec
from agent.sim.paths import (
    CELL_M,
    clearance_grid,
    path_field,
    point_clearance,
    reference_radius_m,
    shortest_path,
    turning_radius_m,
)
from agent.sim.world import World

H = CELL_M


def _room(*walls: tuple[tuple[float, float], ...], **kwargs: object) -> World:
    """A 6 m x 4 m room from (0, 0) to (6, 4) with more walls, boxes or cylinders."""
    outline = ((0.0, 0.0), (6.0, 0.0), (6.0, 4.0), (0.0, 4.0), (0.0, 0.0))
    return World.build(walls=[(outline, 1.0), *((w, 1.0) for w in walls)], **kwargs)  # type: ignore[arg-type]


def _divided(gap_m: float) -> World:
    """The room split at x = 3 by a wall with a gap of ``gap_m`` centred on y = 2."""
    half = 0.5 * gap_m
    return _room(((3.0, 0.0), (3.0, 2.0 - half)), ((3.0, 2.0 + half), (3.0, 4.0)))


def test_radii_follow_the_vehicle() -> None:
    spec = VehicleSpec()
    assert reference_radius_m(spec) == pytest.approx(0.3 - math.sqrt(2) * H)
    assert turning_radius_m(spec) == pytest.approx(0.5 + 0.1)


def test_empty_room_gives_the_straight_line_exactly() -> None:
    world = _room()
    for start, goal in (
        ((0.7, 0.8), (5.2, 3.1)),
        ((1.0, 2.0), (5.0, 2.0)),
        ((3.0, 1.0), (3.1, 3.0)),
    ):
        path = shortest_path(world, start, goal, 0.5)
        assert path.length_m == pytest.approx(math.dist(start, goal), abs=1e-12)
        np.testing.assert_array_equal(path.waypoints, [start, goal])


@pytest.mark.parametrize(
    ("gap_m", "passes"), [(0.85, False), (0.9, False), (1.1, True), (1.3, True)]
)
def test_a_gap_narrower_than_the_disc_blocks(gap_m: float, passes: bool) -> None:
    # Radius 0.5: the gap must be 1.0 m wide, give or take the grid's error: a gap narrower
    # than 2 (r - h/4 - h/sqrt 2) = 0.904 m surely blocks, one wider than 2 (r + h/sqrt 2)
    # = 1.071 m surely passes.
    path = shortest_path(_divided(gap_m), (1.0, 2.0), (5.0, 2.0), 0.5)
    if passes:
        assert path.length_m == pytest.approx(4.0, abs=1e-12)  # straight through the gap
    else:
        assert path.length_m == math.inf
        assert path.waypoints.shape == (0, 2)


def test_detour_round_a_wall_end_matches_the_tangent_and_arc() -> None:
    # A wall from (0, -5) to (0, 1) in a 10 m room; a disc of r = 0.3 from (-2, 0) to
    # (2, 0) goes round the end: two tangents to the circle of radius r about (0, 1) and
    # the arc between them.
    outline = ((-5.0, -5.0), (5.0, -5.0), (5.0, 5.0), (-5.0, 5.0), (-5.0, -5.0))
    world = World.build(walls=[(outline, 1.0), (((0.0, -5.0), (0.0, 1.0)), 1.0)])
    r = 0.3
    d = math.hypot(2.0, 1.0)
    tangent = math.sqrt(d * d - r * r)
    heading = math.atan2(1.0, 2.0) + math.asin(r / d)  # of the first tangent
    exact = 2.0 * tangent + r * 2.0 * heading
    path = shortest_path(world, (-2.0, 0.0), (2.0, 0.0), r)
    # Tolerance: the 16-neighbour bound (2.8 %) plus the free space's error at the wall end
    # (about h, 5 cm, on a turn of 2 x 56 degrees).
    assert abs(path.length_m - exact) <= 0.028 * exact + H
    assert path.waypoints.shape[0] >= 3  # it bends round the end


def test_grid_clearance_is_within_the_stated_error(rng: np.random.Generator) -> None:
    # Walls at random and cylinders: outside the cylinders the exact distance d of each cell
    # centre and the grid's e obey e - (h/4 + h/sqrt 2) <= d <= e + h/sqrt 2.
    walls = [(rng.uniform(0.0, 6.0, (2, 2)), 1.0) for _ in range(6)]
    cylinders = [(rng.uniform(1.0, 5.0, 2), float(rng.uniform(0.1, 0.5)), 1.0) for _ in range(4)]
    world = World.build(walls=walls, cylinders=cylinders)
    grid = clearance_grid(world)
    rows, cols = grid.shape
    centres = grid.centres(*np.divmod(np.arange(rows * cols), cols))
    d = point_clearance(world, centres)
    e = grid.clearance_m.ravel()
    outside = d > 0.0
    assert np.all(d[outside] <= e[outside] + H / math.sqrt(2) + 1e-12)
    assert np.all(d >= e - (H / 4 + H / math.sqrt(2)) - 1e-12)


def test_boxes_and_cylinders_are_solid_rooms_are_not() -> None:
    world = _room(boxes=[((2.0, 2.0), (1.6, 1.6), 0.3, 1.0)], cylinders=[((4.5, 2.0), 0.6, 1.0)])
    grid = clearance_grid(world)
    i, j, _ = grid.cells(np.array([[2.0, 2.0], [4.5, 2.0], [1.0, 3.5]]))
    assert grid.clearance_m[i[0], j[0]] == 0.0  # inside the box
    assert grid.clearance_m[i[1], j[1]] == 0.0  # inside the cylinder
    assert grid.clearance_m[i[2], j[2]] == pytest.approx(0.5, abs=0.05)  # in the room
    # A disc that would fit inside the box finds no way out of it.
    assert shortest_path(world, (2.0, 2.0), (0.5, 0.5), 0.2).length_m == math.inf


def test_start_or_goal_where_the_disc_does_not_fit_gives_no_path() -> None:
    world = _room()
    assert shortest_path(world, (0.2, 2.0), (5.0, 2.0), 0.5).length_m == math.inf
    assert shortest_path(world, (1.0, 2.0), (5.8, 2.0), 0.5).length_m == math.inf


def test_turning_paths_keep_the_circumradius_clear(rng: np.random.Generator) -> None:
    # Along a path for the turning radius the true clearance is at least the radius less
    # 1.8 h, which the margin covers: every point of the path is clear of the circumcircle.
    boxes = [
        (rng.uniform(1.0, 9.0, 2), rng.uniform(0.2, 1.0, 2), float(rng.uniform(0, 3)), 1.0)
        for _ in range(12)
    ]
    outline = ((0.0, 0.0), (10.0, 0.0), (10.0, 8.0), (0.0, 8.0), (0.0, 0.0))
    world = World.build(walls=[(outline, 1.0)], boxes=boxes)
    grid = clearance_grid(world)
    radius = turning_radius_m()
    free = np.argwhere(grid.clearance_m >= radius + 0.2)
    pick = rng.choice(free.shape[0], size=20, replace=False)
    starts = grid.centres(free[pick, 0], free[pick, 1])
    field = path_field(grid, starts[0], radius)
    found = 0
    for goal in starts[1:]:
        path = field.path_to(goal)
        if not math.isfinite(path.length_m):
            continue
        found += 1
        steps = np.linspace(0.0, 1.0, 50)[:, None, None]
        a, b = path.waypoints[:-1], path.waypoints[1:]
        samples = (a + steps * (b - a)).reshape(-1, 2)
        assert point_clearance(world, samples).min() >= VehicleSpec().circumradius_m
        # No shorter than the straight line, no longer than the grid's distance.
        assert path.length_m >= math.dist(starts[0], goal) - 1e-9
        i, j, _ = grid.cells(goal[None])
        assert path.length_m <= field.distance_m[i[0], j[0]] + 1e-9
    assert found >= 5


def test_turning_paths_through_gaps_keep_the_circumradius_clear() -> None:
    # Gaps about the vehicle's 1.0 m circumdiameter: a path, where one is found, clears the
    # circumcircle everywhere (a 0.5 m disc, with no margin, squeezes through 0.95 m).
    spec = VehicleSpec()
    found = 0
    for gap_m in np.arange(0.9, 1.5, 0.025):
        world = _divided(float(gap_m))
        path = shortest_path(world, (1.0, 1.7), (5.0, 2.6), turning_radius_m(spec))
        if math.isfinite(path.length_m):
            found += 1
            steps = np.linspace(0.0, 1.0, 200)[:, None, None]
            a, b = path.waypoints[:-1], path.waypoints[1:]
            samples = (a + steps * (b - a)).reshape(-1, 2)
            assert point_clearance(world, samples).min() >= spec.circumradius_m
    assert found >= 5


def test_limit_stops_the_search() -> None:
    grid = clearance_grid(_room())
    field = path_field(grid, (1.0, 2.0), 0.5, limit_m=2.0)
    assert field.path_to((2.5, 2.0)).length_m == pytest.approx(1.5)
    assert field.path_to((5.0, 2.0)).length_m == math.inf


def test_point_clearance_by_hand() -> None:
    world = _room(cylinders=[((3.0, 2.0), 0.5, 1.0)])
    got = point_clearance(world, [[1.0, 1.0], [3.0, 3.0], [3.2, 2.0], [-1.0, -1.0]])
    np.testing.assert_allclose(got, [1.0, 0.5, 0.0, math.sqrt(2.0)])
    assert point_clearance(World.build(), [0.0, 0.0])[0] == math.inf


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"cell_m": 0.0}, "cell_m"),
        ({"cell_m": math.nan}, "cell_m"),
        ({"pad_m": -1.0}, "pad_m"),
        ({"cell_m": 0.001, "pad_m": 100.0}, "exceed"),
    ],
)
def test_clearance_grid_refuses_bad_arguments(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        clearance_grid(_room(), **kwargs)


def test_path_functions_refuse_bad_points() -> None:
    grid = clearance_grid(_room())
    with pytest.raises(ValueError, match="start_xy"):
        path_field(grid, (math.nan, 0.0), 0.5)
    with pytest.raises(ValueError, match="radius_m"):
        path_field(grid, (1.0, 1.0), -0.1)
    with pytest.raises(ValueError, match="goal_xy"):
        path_field(grid, (1.0, 1.0), 0.5).path_to((1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="start_xy and goal_xy"):
        shortest_path(_room(), (1.0, 1.0), (math.inf, 1.0), 0.5)
