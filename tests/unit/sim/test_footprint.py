"""Tests of agent.sim.footprint: the vehicle's outline against segments, circles and movers."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from agent.kinematics.vehicle import VehicleSpec
from agent.sim.footprint import (
    outline_clearance,
    outline_clearances,
    outline_clearances_reference,
    outline_corners,
)
from agent.sim.world import World, world_from_obstacles

pytestmark = pytest.mark.filterwarnings("error")

# The default outline: 0.8 m x 0.6 m, half sides 0.4 and 0.3.
A, B = 0.4, 0.3


def _wall(*points: tuple[float, float]) -> World:
    return world_from_obstacles(walls=[(points, 1.0)])


def _cylinder(x: float, y: float, r: float) -> World:
    return world_from_obstacles(cylinders=[((x, y), r, 1.0)])


@pytest.mark.parametrize(
    ("points", "expected"),
    [
        (((-1.0, 0.0), (1.0, 0.0)), 0.0),  # crosses it lengthwise, both ends outside
        (((-1.0, -1.0), (1.0, 1.0)), 0.0),  # crosses it diagonally, both ends outside
        (((-0.1, 0.0), (0.1, 0.1)), 0.0),  # entirely inside
        (((0.2, 0.0), (2.0, 0.5)), 0.0),  # one end inside
        (((A, -1.0), (A, 1.0)), 0.0),  # touches the front face: contact is a collision
        (((-1.0, 0.5), (1.0, 0.5)), 0.2),  # parallel to the left side, 0.2 m off
        (((0.6, -0.2), (0.6, 0.2)), 0.2),  # parallel to the front face, within its span
        (((0.6, 0.0), (2.0, 0.0)), 0.2),  # end-on: its near end 0.2 m ahead
        (((0.7, 0.7), (1.5, 0.9)), math.hypot(0.3, 0.4)),  # its end nearest a corner
        (((0.5, 0.5), (0.9, 0.1)), 0.3 / math.sqrt(2.0)),  # a corner nearest its middle
        # Across the corner's quadrant, its ends level with the outline in x and in y: only
        # the segment's own normal separates them.
        (((0.3, 0.6), (0.7, 0.2)), 0.2 / math.sqrt(2.0)),
    ],
)
def test_segments_against_the_outline(
    points: tuple[tuple[float, float], ...], expected: float
) -> None:
    clearance, obstacle = outline_clearance(_wall(*points), (0.0, 0.0, 0.0))
    assert clearance == pytest.approx(expected, abs=1e-12)
    assert obstacle == 0


def test_corner_nearest_the_middle_of_a_segment_is_not_an_end() -> None:
    # The line x + y = 1 passes the corner (0.4, 0.3) at 0.3/√2 = 0.212 m; its ends are
    # 0.224 m and 0.5 m from the outline: only the corner-to-segment distance is right.
    ends = [math.hypot(0.1, 0.2), 0.5]
    clearance, _ = outline_clearance(_wall((0.5, 0.5), (0.9, 0.1)), (0.0, 0.0, 0.0))
    assert clearance < min(ends) - 0.01


@pytest.mark.parametrize(("dx", "dy", "r"), [(0.3, 0.4, 0.1), (0.05, 0.12, 0.01), (1.0, 2.0, 0.5)])
def test_a_circle_off_a_corner(dx: float, dy: float, r: float) -> None:
    for sx, sy in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        world = _cylinder(sx * (A + dx), sy * (B + dy), r)
        clearance, obstacle = outline_clearance(world, (0.0, 0.0, 0.0))
        assert clearance == pytest.approx(math.hypot(dx, dy) - r, abs=1e-12)
        assert obstacle == 0


def test_circles_beside_inside_and_overlapping() -> None:
    assert outline_clearance(_cylinder(0.0, 0.5, 0.1), (0, 0, 0))[0] == pytest.approx(0.1)
    assert outline_clearance(_cylinder(0.9, 0.0, 0.25), (0, 0, 0))[0] == pytest.approx(0.25)
    assert outline_clearance(_cylinder(0.0, 0.0, 0.05), (0, 0, 0))[0] == 0.0  # inside
    assert outline_clearance(_cylinder(0.0, 0.35, 0.1), (0, 0, 0))[0] == 0.0  # overlaps
    # Diagonally off a corner but within r of it: overlap.
    assert outline_clearance(_cylinder(A + 0.06, B + 0.08, 0.1), (0, 0, 0))[0] == 0.0


def test_rotated_and_moved_outline() -> None:
    # Turned by 90°, at (1, 2): it spans x 0.7 … 1.3 and y 1.6 … 2.4.
    pose = (1.0, 2.0, math.pi / 2)
    assert outline_clearance(_wall((1.5, 0.0), (1.5, 4.0)), pose)[0] == pytest.approx(0.2)
    assert outline_clearance(_wall((0.0, 2.9), (2.0, 2.9)), pose)[0] == pytest.approx(0.5)
    assert outline_clearance(_cylinder(1.0, 2.9, 0.1), pose)[0] == pytest.approx(0.4)
    # Turned by 45° at the origin: its corner (0.4, 0.3) lies at (0.0707, 0.495).
    corner = outline_corners((0.0, 0.0, math.pi / 4))[1]
    np.testing.assert_allclose(corner, [0.1 / math.sqrt(2), 0.7 / math.sqrt(2)], atol=1e-12)
    wall = _wall((-1.0, 0.7), (1.0, 0.7))
    assert outline_clearance(wall, (0.0, 0.0, math.pi / 4))[0] == pytest.approx(0.7 - corner[1])
    # A wider vehicle touches it.
    wide = VehicleSpec(length_m=1.0, width_m=1.0)
    assert outline_clearance(wall, (0.0, 0.0, math.pi / 4), vehicle=wide)[0] == 0.0


def test_obstacle_ids_follow_the_world() -> None:
    world = world_from_obstacles(
        walls=[(((5.0, -5.0), (5.0, 5.0)), 1.0)],  # id 0: 4.6 m ahead
        boxes=[((0.0, 3.0), (1.0, 1.0), 0.0, 1.0)],  # id 1: 2.2 m to the left
        cylinders=[((-2.0, 0.0), 0.5, 1.0), ((0.0, -1.0), 0.2, 1.0)],  # ids 2 (1.1 m), 3 (0.5)
    )
    assert world.mover_id_base == 4
    clearance, obstacle = outline_clearance(world, (0.0, 0.0, 0.0))
    assert clearance == pytest.approx(0.5) and obstacle == 3
    # A mover nearer still: its id follows the static obstacles.
    movers_xy, radii = np.array([[9.0, 9.0], [0.0, 0.6]]), np.array([0.2, 0.2])
    clearance, obstacle = outline_clearance(world, (0.0, 0.0, 0.0), movers_xy, radii)
    assert clearance == pytest.approx(0.1) and obstacle == 5
    # The box face nearest: moved so that the box is 0.05 m off the left side.
    clearance, obstacle = outline_clearance(world, (0.0, 2.15, 0.0))
    assert clearance == pytest.approx(0.05) and obstacle == 1


def test_an_empty_world_has_infinite_clearance() -> None:
    empty = world_from_obstacles()
    assert outline_clearance(empty, (1.0, 2.0, 3.0)) == (math.inf, -1)
    d, ids = outline_clearances(empty, np.zeros((4, 3)))
    assert np.all(np.isinf(d)) and np.all(ids == -1)
    # Movers alone.
    clearance, obstacle = outline_clearance(empty, (0, 0, 0), [[0.0, 1.0]], [0.2])
    assert clearance == pytest.approx(0.5) and obstacle == 0


def test_batched_equals_one_at_a_time_with_movers_per_pose(rng: np.random.Generator) -> None:
    world = world_from_obstacles(
        walls=[(((-3.0, -2.0), (3.0, -2.0), (3.0, 2.0)), 1.0)],
        boxes=[((1.0, 1.0), (0.5, 0.3), 0.4, 1.0)],
        cylinders=[((-1.0, 1.0), 0.3, 1.0)],
    )
    n, m = 300, 2
    poses = np.column_stack(
        [rng.uniform(-3, 3, n), rng.uniform(-2.5, 2.5, n), rng.uniform(-4, 4, n)]
    )
    movers = rng.uniform(-3.0, 3.0, (n, m, 2))
    radii = np.array([0.2, 0.35])
    d, ids = outline_clearances(world, poses, movers, radii)
    assert d.shape == ids.shape == (n,)
    assert 0 < np.count_nonzero(d == 0.0) < n  # some collide, some do not
    for i in range(0, n, 7):
        assert (d[i], ids[i]) == outline_clearance(world, poses[i], movers[i], radii)
    # Movers the same for every pose: (m, 2) broadcasts.
    d_shared, _ = outline_clearances(world, poses, movers[0], radii)
    d_each, _ = outline_clearances(world, poses, np.broadcast_to(movers[0], (n, m, 2)), radii)
    np.testing.assert_array_equal(d_shared, d_each)


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_clearance_equals_its_numpy_reference(seed: int) -> None:
    """The kernel (a broad phase, then exact distances) against every pose tested against
    every primitive in numpy: equal to the bit, obstacle ids too, over random cluttered
    worlds with movers per pose; about a third of the poses in contact, and duplicated
    primitives, so that ties go to the first of equals in both."""
    rng = np.random.default_rng(seed)
    boxes = [(tuple(rng.uniform(-4, 4, 2)), tuple(rng.uniform(0.2, 1.0, 2)),
              float(rng.uniform(-3, 3)), 1.0) for _ in range(8)]  # fmt: skip
    cylinders = [(tuple(rng.uniform(-4, 4, 2)), float(rng.uniform(0.05, 0.4)), 1.0)
                 for _ in range(6)]  # fmt: skip
    world = world_from_obstacles(
        walls=[(((-5.0, -5.0), (5.0, -5.0), (5.0, 5.0), (-5.0, 5.0), (-5.0, -5.0)), 1.0)],
        boxes=boxes + boxes[:2],
        cylinders=cylinders + cylinders[:2],
    )
    n, m = 2000, 3
    poses = np.column_stack([rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-10, 10, n)])
    movers = rng.uniform(-5.0, 5.0, (n, m, 2))
    radii = np.array([0.1, 0.3, 0.3])
    for args in ((), (movers, radii), (movers[0], radii)):
        d, ids = outline_clearances(world, poses, *args)
        ref_d, ref_ids = outline_clearances_reference(world, poses, *args)
        np.testing.assert_array_equal(d, ref_d)
        np.testing.assert_array_equal(ids, ref_ids)
        assert 0.2 * n < np.count_nonzero(d == 0.0) < 0.6 * n


def _perimeter(pose: np.ndarray, spacing: float) -> np.ndarray:
    """Points every ``spacing`` metres (or closer) along the outline at ``pose``."""
    corners = outline_corners(pose)
    closed = np.vstack([corners, corners[:1]])
    pts = []
    for a, b in itertools.pairwise(closed):
        k = math.ceil(float(np.hypot(*(b - a))) / spacing)
        pts.append(a + np.linspace(0.0, 1.0, k + 1)[:, None] * (b - a))
    return np.vstack(pts)


def _inside(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    c, s = math.cos(pose[2]), math.sin(pose[2])
    dx, dy = points[:, 0] - pose[0], points[:, 1] - pose[1]
    inside: np.ndarray = (np.abs(c * dx + s * dy) <= A) & (np.abs(c * dy - s * dx) <= B)
    return inside


def test_against_dense_point_sampling(rng: np.random.Generator) -> None:
    """Random segments and circles near random poses, against a reference that samples the
    outline's perimeter and the segment every 1 mm: each sampled set is within 0.5 mm of
    the true one, so the reference is within 1 mm of the exact distance (and a segment that
    enters the outline by more than 1 mm puts a sample inside it: reference 0)."""
    spacing = 1e-3
    tolerance = spacing
    exact_zero = 0
    for _ in range(150):
        pose = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-math.pi, math.pi)])
        a = pose[:2] + rng.uniform(-1.2, 1.2, 2)
        b = a + rng.uniform(-1.0, 1.0, 2)
        center, r = pose[:2] + rng.uniform(-1.2, 1.2, 2), float(rng.uniform(0.01, 0.4))
        world = world_from_obstacles(walls=[((tuple(a), tuple(b)), 1.0)])
        got, _ = outline_clearance(world, pose)
        tree = cKDTree(_perimeter(pose, spacing))
        k = math.ceil(float(np.hypot(*(b - a))) / spacing)
        seg = a + np.linspace(0.0, 1.0, k + 1)[:, None] * (b - a)
        ref = 0.0 if _inside(pose, seg).any() else float(np.min(tree.query(seg)[0]))
        assert got == pytest.approx(ref, abs=tolerance)
        exact_zero += got == 0.0
        got_c, _ = outline_clearance(_cylinder(float(center[0]), float(center[1]), r), pose)
        to_center = 0.0 if _inside(pose, center[None, :])[0] else float(tree.query(center)[0])
        assert got_c == pytest.approx(max(to_center - r, 0.0), abs=tolerance)
    assert 10 < exact_zero < 140  # both kinds of case were drawn


def test_bad_input_is_refused() -> None:
    world = _cylinder(1.0, 0.0, 0.1)
    with pytest.raises(ValueError, match="pose must be"):
        outline_clearance(world, (0.0, 0.0))
    with pytest.raises(ValueError, match="poses must be"):
        outline_clearances(world, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="finite"):
        outline_clearances(world, [[0.0, math.nan, 0.0]])
    with pytest.raises(ValueError, match="mover_xy must be"):
        outline_clearances(world, np.zeros((3, 3)), np.zeros((2, 2, 2)), [0.1, 0.1])
    with pytest.raises(ValueError, match="given together"):
        outline_clearance(world, (0.0, 0.0, 0.0), [[1.0, 1.0]])
    with pytest.raises(ValueError, match="mover_radius_m"):
        outline_clearance(world, (0.0, 0.0, 0.0), [[1.0, 1.0]], [0.0])
