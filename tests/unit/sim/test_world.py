"""Tests of agent.sim.world: world files, worlds built in code, ray casting and line of sight."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from agent.errors import WorldFileError
from agent.sim import world as world_module
from agent.sim.world import (
    RayHits,
    World,
    cast_rays,
    load_world,
    parse_world,
    ray_directions,
    segment_clear,
    world_from_obstacles,
)

pytestmark = pytest.mark.filterwarnings("error")

REPO = Path(__file__).resolve().parents[3]
EXAMPLE_WORLDS = REPO / "worlds"
TEST_WORLDS = REPO / "tests" / "data" / "worlds"

FloatArray = npt.NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def one_ray(
    world: World,
    origin: tuple[float, float],
    heading_rad: float,
    **kwargs: float,
) -> tuple[float, FloatArray, float, int]:
    """Cast a single ray; return (distance, normal, reflectivity, obstacle)."""
    hits = cast_rays(world, np.array(origin), ray_directions(np.array([heading_rad])), **kwargs)
    return (
        float(hits.distance_m[0]),
        hits.normal[0],
        float(hits.reflectivity[0]),
        int(hits.obstacle[0]),
    )


def cross(u: tuple[float, float], v: tuple[float, float]) -> float:
    return u[0] * v[1] - u[1] * v[0]


def reference_cast(
    world: World,
    origin: tuple[float, float],
    direction: tuple[float, float],
    min_range: float = 0.0,
    max_range: float = math.inf,
) -> tuple[float, int]:
    """Slow per-ray reference: (distance, obstacle id), (inf, -1) for no hit."""
    best, best_obstacle = math.inf, -1
    ox, oy = origin
    dx, dy = direction
    for a, b, oid in zip(
        world.segments_start.tolist(),
        world.segments_end.tolist(),
        world.segments_obstacle.tolist(),
        strict=True,
    ):
        e = (b[0] - a[0], b[1] - a[1])
        den = cross((dx, dy), e)
        if abs(den) < 1e-14:
            continue
        w = (a[0] - ox, a[1] - oy)
        t = cross(w, e) / den
        u = cross(w, (dx, dy)) / den
        if 0.0 <= u <= 1.0 and min_range < t <= max_range and t < best:
            best, best_obstacle = t, oid
    for c, r, oid in zip(
        world.circles_center.tolist(),
        world.circles_radius.tolist(),
        world.circles_obstacle.tolist(),
        strict=True,
    ):
        fx, fy = ox - c[0], oy - c[1]
        bq = fx * dx + fy * dy
        disc = bq * bq - (fx * fx + fy * fy - r * r)
        if disc < 0.0:
            continue
        for t in (-bq - math.sqrt(disc), -bq + math.sqrt(disc)):
            if min_range < t <= max_range:
                if t < best:
                    best, best_obstacle = t, oid
                break
    return best, best_obstacle


def random_world(rng: np.random.Generator, n_walls: int, n_boxes: int, n_cyl: int) -> World:
    """Random walls (random walks of 2-5 points), boxes and cylinders in a 12 m square."""
    walls = []
    for _ in range(n_walls):
        steps = rng.uniform(-1.0, 1.0, (int(rng.integers(2, 6)), 2))
        points = np.cumsum(steps, axis=0) + rng.uniform(-6.0, 6.0, 2)
        walls.append((points, float(rng.uniform(0.2, 3.0))))
    boxes = [
        (rng.uniform(-6.0, 6.0, 2), rng.uniform(0.1, 1.0, 2), float(rng.uniform(-3.0, 3.0)), 1.0)
        for _ in range(n_boxes)
    ]
    cylinders = [
        (rng.uniform(-6.0, 6.0, 2), float(rng.uniform(0.05, 0.5)), float(rng.uniform(0.2, 2.0)))
        for _ in range(n_cyl)
    ]
    return world_from_obstacles(walls, boxes, cylinders)


def check_single_line_error(exc: WorldFileError, path: Path | None, *fragments: str) -> None:
    text = str(exc)
    assert "\n" not in text and "\r" not in text
    prefix = "world: " if path is None else f"world file {path}: "
    assert text.startswith(prefix), text
    for fragment in fragments:
        assert fragment in text, text


WALL_AT_2 = world_from_obstacles(walls=[([(2.0, -1.0), (2.0, 1.0)], 0.7)])


# --------------------------------------------------------------------------------------------
# Ray casting: analytic cases
# --------------------------------------------------------------------------------------------


def test_ray_straight_at_wall() -> None:
    distance, normal, refl, obstacle = one_ray(WALL_AT_2, (0.0, 0.0), 0.0)
    assert distance == pytest.approx(2.0, abs=1e-12)
    np.testing.assert_allclose(normal, [-1.0, 0.0], atol=1e-12)
    assert refl == 0.7
    assert obstacle == 0


def test_ray_from_behind_gets_normal_toward_it() -> None:
    distance, normal, _, _ = one_ray(WALL_AT_2, (3.0, 0.0), math.pi)
    assert distance == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(normal, [1.0, 0.0], atol=1e-12)


@pytest.mark.parametrize("angle_deg", [45.0, -30.0, 60.0])
def test_ray_at_angle_to_wall(angle_deg: float) -> None:
    world = world_from_obstacles(walls=[([(2.0, -5.0), (2.0, 5.0)], 1.0)])
    angle = math.radians(angle_deg)
    distance, normal, _, _ = one_ray(world, (0.0, 0.0), angle)
    assert distance == pytest.approx(2.0 / math.cos(angle), rel=1e-12)
    np.testing.assert_allclose(normal, [-1.0, 0.0], atol=1e-12)


def test_ray_missing_the_end_of_a_segment() -> None:
    assert one_ray(WALL_AT_2, (0.0, 0.0), math.atan2(1.01, 2.0))[3] == -1
    distance, normal, refl, obstacle = one_ray(WALL_AT_2, (0.0, 0.0), math.atan2(1.01, 2.0))
    assert distance == math.inf
    assert np.all(np.isnan(normal)) and math.isnan(refl) and obstacle == -1
    assert one_ray(WALL_AT_2, (0.0, 0.0), math.atan2(0.99, 2.0))[3] == 0


def test_ray_parallel_or_collinear_with_segment_does_not_hit() -> None:
    # Parallel beside the wall, collinear with it from outside, and collinear along it.
    origins = np.array([[0.0, 0.0], [2.0, -5.0], [2.0, 0.0], [2.0, -1.0]])
    directions = np.array([[0.0, 1.0], [0.0, 1.0], [0.0, -1.0], [0.0, 1.0]])
    hits = cast_rays(WALL_AT_2, origins, directions)
    assert np.all(hits.distance_m == np.inf)
    assert np.all(hits.obstacle == -1)
    tilted = world_from_obstacles(walls=[([(0.0, 0.0), (3.0, 1.0)], 1.0)])
    along = cast_rays(tilted, np.array([-3.0, -1.0]), np.array([3.0, 1.0]))
    assert along.obstacle[0] == -1


def test_cylinder_head_on_and_off_centre() -> None:
    world = world_from_obstacles(cylinders=[((1.2, 0.0), 0.1, 0.5)])
    distance, normal, refl, obstacle = one_ray(world, (0.0, 0.0), 0.0)
    assert distance == pytest.approx(1.1, abs=1e-12)
    np.testing.assert_allclose(normal, [-1.0, 0.0], atol=1e-12)
    assert (refl, obstacle) == (0.5, 0)

    offset = 0.06
    distance, normal, _, _ = one_ray(world, (0.0, offset), 0.0)
    half_chord = math.sqrt(0.1**2 - offset**2)
    assert distance == pytest.approx(1.2 - half_chord, abs=1e-12)
    np.testing.assert_allclose(normal, [-half_chord / 0.1, offset / 0.1], atol=1e-12)

    assert one_ray(world, (0.0, 0.1001), 0.0)[3] == -1


def test_ray_starting_inside_cylinder_meets_far_side_from_inside() -> None:
    world = world_from_obstacles(cylinders=[((1.0, 1.0), 0.5, 1.0)])
    distance, normal, _, obstacle = one_ray(world, (1.0, 1.0), math.pi / 2)
    assert distance == pytest.approx(0.5, abs=1e-12)
    np.testing.assert_allclose(normal, [0.0, -1.0], atol=1e-12)
    assert obstacle == 0


def test_ray_starting_inside_box_meets_the_face_from_inside() -> None:
    world = world_from_obstacles(boxes=[((0.0, 0.0), (2.0, 1.0), 0.0, 1.0)])
    distance, normal, _, _ = one_ray(world, (0.0, 0.0), 0.0)
    assert distance == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(normal, [-1.0, 0.0], atol=1e-12)


def test_nearest_of_several_obstacles_wins() -> None:
    world = load_world(EXAMPLE_WORLDS / "box_before_wall.toml")
    box = next(o for o in world.obstacles if o.kind == "box")
    wall = next(o for o in world.obstacles if o.kind == "wall")
    origins = np.array([[0.0, 0.3], [0.0, -0.5]])
    hits = cast_rays(world, origins, np.array([1.0, 0.0]))
    np.testing.assert_allclose(hits.distance_m, [1.0, 2.0], atol=1e-12)
    assert hits.obstacle.tolist() == [box.id, wall.id]
    # A cylinder in front of a box in front of a wall, in any order of the arguments.
    mixed = world_from_obstacles(
        walls=[([(3.0, -1.0), (3.0, 1.0)], 1.0)],
        boxes=[((2.0, 0.0), (0.2, 0.2), 0.0, 1.0)],
        cylinders=[((1.0, 0.0), 0.1, 1.0), ((2.5, 0.0), 0.1, 1.0)],
    )
    distance, _, _, obstacle = one_ray(mixed, (0.0, 0.0), 0.0)
    assert distance == pytest.approx(0.9)
    assert mixed.obstacles[obstacle].kind == "cylinder"
    assert mixed.obstacles[obstacle].index == 0


def test_max_and_min_range() -> None:
    world = load_world(EXAMPLE_WORLDS / "box_before_wall.toml")
    origin = (0.0, 0.3)
    assert one_ray(world, origin, 0.0, max_range_m=0.99)[3] == -1
    assert one_ray(world, origin, 0.0, max_range_m=1.0)[0] == pytest.approx(1.0)  # inclusive
    assert one_ray(world, origin, 0.0, min_range_m=1.0)[0] == pytest.approx(1.4)  # exclusive
    assert one_ray(world, origin, 0.0, min_range_m=1.5)[0] == pytest.approx(2.0)
    assert one_ray(world, origin, 0.0, min_range_m=1.5, max_range_m=1.9)[3] == -1


def test_rotated_box_faces() -> None:
    # Yaw 90 degrees: the box's width (0.5) now lies along world x.
    turned = world_from_obstacles(boxes=[((2.0, 0.0), (1.0, 0.5), math.pi / 2, 1.0)])
    distance, normal, _, _ = one_ray(turned, (0.0, 0.0), 0.0)
    assert distance == pytest.approx(1.75, abs=1e-12)
    np.testing.assert_allclose(normal, [-1.0, 0.0], atol=1e-12)
    distance, normal, _, _ = one_ray(turned, (2.0, 3.0), -math.pi / 2)
    assert distance == pytest.approx(2.5, abs=1e-12)
    np.testing.assert_allclose(normal, [0.0, 1.0], atol=1e-12)

    # A unit square turned 45 degrees: a ray 0.1 m above the axis meets the upper-left face,
    # n . (q - c) = 0.5 with n = (-1, 1) / sqrt(2).
    diamond = world_from_obstacles(boxes=[((2.0, 0.0), (1.0, 1.0), math.pi / 4, 1.0)])
    distance, normal, _, _ = one_ray(diamond, (0.0, 0.1), 0.0)
    assert distance == pytest.approx(2.1 - 0.5 * math.sqrt(2.0), abs=1e-12)
    np.testing.assert_allclose(normal, np.array([-1.0, 1.0]) / math.sqrt(2.0), atol=1e-12)
    distance, _, _, _ = one_ray(diamond, (0.0, 0.0), 0.0)
    assert distance == pytest.approx(2.0 - 0.5 * math.sqrt(2.0), abs=1e-12)  # the corner


@pytest.mark.parametrize("block", [None, (7, 200)])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_rays_agree_with_slow_reference(
    seed: int, block: tuple[int, int] | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    if block is not None:  # many small blocks and groups of blocks
        monkeypatch.setattr(world_module, "_BLOCK_RAYS", block[0])
        monkeypatch.setattr(world_module, "_BLOCK_ELEMENTS", block[1])
    rng = np.random.default_rng(seed)
    world = random_world(rng, 4, 8, 5)
    n = 400
    scan_origin = rng.uniform(-2.0, 2.0, 2)
    scan = ray_directions(np.linspace(-math.pi, math.pi, n, endpoint=False))
    origins = np.concatenate([np.tile(scan_origin, (n, 1)), rng.uniform(-7.0, 7.0, (n, 2))])
    directions = np.concatenate([scan, ray_directions(rng.uniform(-math.pi, math.pi, n))])
    jittered = scan_origin + rng.normal(0.0, 0.3, (n, 2))  # a scan from a moving origin
    cases = [(origins, directions), (scan_origin, scan), (jittered, scan)]
    for min_range, max_range in [(0.0, math.inf), (0.5, 4.0)]:
        for o, d in cases:
            hits = cast_rays(world, o, d, max_range_m=max_range, min_range_m=min_range)
            o_all = np.broadcast_to(o, d.shape)
            expected = [
                reference_cast(world, (ox, oy), (dx, dy), min_range, max_range)
                for (ox, oy), (dx, dy) in zip(o_all.tolist(), d.tolist(), strict=True)
            ]
            exp_distance = np.array([e[0] for e in expected])
            exp_obstacle = np.array([e[1] for e in expected])
            np.testing.assert_allclose(hits.distance_m, exp_distance, rtol=1e-9, atol=1e-9)
            np.testing.assert_array_equal(hits.obstacle, exp_obstacle)
            hit = hits.hit
            assert hit.any() and (~hit).any()
            np.testing.assert_allclose(np.hypot(*hits.normal[hit].T), 1.0, atol=1e-12)
            assert np.all(np.sum(hits.normal[hit] * d[hit], axis=1) <= 1e-12)
            assert np.all(np.isnan(hits.normal[~hit])) and np.all(np.isnan(hits.reflectivity[~hit]))
            refl = [world.obstacles[i].reflectivity for i in hits.obstacle[hit].tolist()]
            np.testing.assert_array_equal(hits.reflectivity[hit], refl)


def test_ray_hits_are_read_only_and_shaped() -> None:
    hits = cast_rays(WALL_AT_2, np.zeros(2), ray_directions(np.linspace(-1.0, 1.0, 5)))
    assert isinstance(hits, RayHits)
    assert hits.distance_m.shape == (5,) and hits.normal.shape == (5, 2)
    assert hits.reflectivity.shape == (5,) and hits.obstacle.dtype == np.int64
    for arr in (hits.distance_m, hits.normal, hits.reflectivity, hits.obstacle):
        assert not arr.flags.writeable


def test_cast_rays_shapes_and_empty_inputs() -> None:
    one = cast_rays(WALL_AT_2, np.zeros(2), np.array([2.0, 0.0]))  # directions are normalised
    assert one.distance_m.shape == (1,) and one.distance_m[0] == pytest.approx(2.0)
    none = cast_rays(WALL_AT_2, np.zeros((0, 2)), np.zeros((0, 2)))
    assert none.distance_m.shape == (0,) and none.normal.shape == (0, 2)
    empty = cast_rays(world_from_obstacles(), np.zeros(2), ray_directions(np.zeros(3)))
    assert np.all(empty.distance_m == np.inf) and np.all(empty.obstacle == -1)
    assert ray_directions(math.pi / 2).shape == (2,)
    np.testing.assert_allclose(
        ray_directions(np.array([0.0, math.pi / 2])), [[1.0, 0.0], [0.0, 1.0]], atol=1e-15
    )


@pytest.mark.parametrize(
    ("origins", "directions", "kwargs"),
    [
        (np.zeros(2), np.zeros(2), {}),
        (np.array([np.nan, 0.0]), np.array([1.0, 0.0]), {}),
        (np.zeros((3, 2)), np.ones((2, 2)), {}),
        (np.zeros(3), np.ones(3), {}),
        (np.zeros(2), np.array([1.0, 0.0]), {"max_range_m": 1.0, "min_range_m": 1.0}),
        (np.zeros(2), np.array([1.0, 0.0]), {"min_range_m": -1.0}),
    ],
)
def test_cast_rays_rejects_bad_arguments(
    origins: FloatArray, directions: FloatArray, kwargs: dict[str, float]
) -> None:
    with pytest.raises(ValueError):
        cast_rays(WALL_AT_2, origins, directions, **kwargs)


# --------------------------------------------------------------------------------------------
# Line of sight
# --------------------------------------------------------------------------------------------

BOX_AT_1 = world_from_obstacles(
    boxes=[((1.0, 0.0), (0.4, 0.4), 0.0, 1.0)], cylinders=[((0.0, 3.0), 0.5, 1.0)]
)


def test_segment_clear_blocked_and_beside() -> None:
    starts = np.array([[0.0, 0.0], [0.0, 0.5], [0.0, -0.21], [2.0, 0.1]])
    ends = np.array([[2.0, 0.0], [2.0, 0.5], [2.0, -0.21], [0.0, 0.1]])
    assert segment_clear(BOX_AT_1, starts, ends).tolist() == [False, True, True, False]


def test_segment_clear_ending_on_a_surface_is_clear() -> None:
    spot = np.array([0.8, 0.0])  # on the box's near face
    detector = np.array([0.0, 0.05])
    assert segment_clear(BOX_AT_1, spot, detector).tolist() == [True]
    assert segment_clear(BOX_AT_1, detector, spot).tolist() == [True]
    # The margin is what forgives the end: a path ending 0.2 m inside the box is blocked,
    # unless the margin is wider than that.
    inside = np.array([1.0, 0.0])
    assert segment_clear(BOX_AT_1, np.zeros(2), inside).tolist() == [False]
    assert segment_clear(BOX_AT_1, np.zeros(2), inside, margin_m=0.25).tolist() == [True]
    # From the near face through the box: blocked by the far face.
    assert segment_clear(BOX_AT_1, spot, np.array([1.5, 0.0])).tolist() == [False]
    # A spot on a cylinder seen from its own side is visible, from the far side is not.
    on_cylinder = np.array([0.0, 2.5])
    assert segment_clear(BOX_AT_1, on_cylinder, np.zeros(2)).tolist() == [True]
    assert segment_clear(BOX_AT_1, on_cylinder, np.array([0.0, 4.0])).tolist() == [False]


def test_segment_clear_broadcasts_and_handles_zero_length() -> None:
    ends = np.array([[2.0, 0.0], [2.0, 1.0], [0.0, 0.0]])
    assert segment_clear(BOX_AT_1, np.zeros(2), ends).tolist() == [False, True, True]


def test_segment_clear_agrees_with_reference() -> None:
    rng = np.random.default_rng(7)
    world = random_world(rng, 3, 6, 4)
    starts = rng.uniform(-6.0, 6.0, (300, 2))
    ends = rng.uniform(-6.0, 6.0, (300, 2))
    clear = segment_clear(world, starts, ends, margin_m=1e-6)
    for s, e, c in zip(starts.tolist(), ends.tolist(), clear.tolist(), strict=True):
        length = math.dist(s, e)
        d = ((e[0] - s[0]) / length, (e[1] - s[1]) / length)
        t, _ = reference_cast(world, (s[0], s[1]), d, 1e-6, length - 1e-6)
        assert c == (t == math.inf)
    assert clear.any() and (~clear).any()


# --------------------------------------------------------------------------------------------
# Worlds: construction, culling
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# World files
# --------------------------------------------------------------------------------------------


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
    check_single_line_error(info.value, tmp_path, "cannot read")
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
