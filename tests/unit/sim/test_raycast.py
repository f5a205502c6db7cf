"""Tests of agent.sim.raycast: ray casting and line of sight."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from agent.sensor.params import SensorParameters
from agent.sim import raycast_kernels
from agent.sim.raycast import RayHits, cast_rays, ray_directions, segment_clear, world_tables
from agent.sim.world import World, world_from_obstacles
from agent.sim.world_file import load_world
from tests.unit.sim.conftest import EXAMPLE_WORLDS, one_ray, random_world

pytestmark = pytest.mark.filterwarnings("error")

FloatArray = npt.NDArray[np.float64]


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


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_rays_agree_with_slow_reference(seed: int) -> None:
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
# The simulator's beams (raycast_kernels.cast_beams) against plain numpy
# --------------------------------------------------------------------------------------------

MAX_RANGE = 6.0
MARGIN = 1e-6


def reference_beams(
    world: World,
    origin: FloatArray,
    head_heading: FloatArray,
    heading: FloatArray,
    theta: FloatArray,
    head: SensorParameters,
) -> tuple[FloatArray, npt.NDArray[np.bool_], FloatArray, FloatArray, npt.NDArray[np.int64]]:
    """Every beam cast, in numpy over cast_rays and segment_clear (no culling, no coarse step):
    (range, visible, reflectivity, cos_view, obstacle)."""
    n = heading.size
    directions = ray_directions(heading)
    hits = cast_rays(world, origin, directions, max_range_m=MAX_RANGE)
    hit = hits.hit
    visible = np.zeros(n, dtype=bool)
    cos_view = np.zeros(n)
    ratio = theta[hit] / head.scan_half_angle_rad
    baseline = head.baseline_m * (1.0 + head.baseline_edge_growth * ratio * ratio)
    hh = head_heading[hit]
    receiver = origin[hit] + baseline[:, None] * np.stack([-np.sin(hh), np.cos(hh)], -1)
    spot = origin[hit] + hits.distance_m[hit][:, None] * directions[hit]
    visible[hit] = segment_clear(world, spot, receiver, margin_m=MARGIN)
    to_receiver = receiver - spot
    to_receiver /= np.linalg.norm(to_receiver, axis=1, keepdims=True)
    cos_view[hit] = np.clip(np.sum(hits.normal[hit] * to_receiver, axis=1), 0.0, 1.0)
    return hits.distance_m, visible, hits.reflectivity, cos_view, hits.obstacle


def kernel_beams(
    world: World,
    origin: FloatArray,
    head_heading: FloatArray,
    heading: FloatArray,
    theta: FloatArray,
    head: SensorParameters,
) -> tuple[FloatArray, npt.NDArray[np.bool_], FloatArray, FloatArray, npt.NDArray[np.int64]]:
    return raycast_kernels.cast_beams(
        origin, head_heading, heading, theta, MAX_RANGE, head.baseline_m,
        head.baseline_edge_growth, head.scan_half_angle_rad, MARGIN, *world_tables(world),
    )  # fmt: skip


def assert_same_beams(
    got: tuple[npt.NDArray[Any], ...], expected: tuple[npt.NDArray[Any], ...]
) -> None:
    range_m, visible, reflectivity, cos_view, obstacle = got
    np.testing.assert_allclose(range_m, expected[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(visible, expected[1])
    np.testing.assert_array_equal(reflectivity, expected[2])
    np.testing.assert_allclose(cos_view, expected[3], rtol=0.0, atol=1e-12)
    np.testing.assert_array_equal(obstacle, expected[4])


def sweep_beams(
    rng: np.random.Generator, n: int, centre_heading: float, pan_rate: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """A sweep's beams from an origin that drifts and turns: (origin, head_heading, heading,
    theta)."""
    theta = np.linspace(-math.radians(20), math.radians(20), n)
    start = rng.uniform(-3.0, 3.0, 2)
    origin = start + np.cumsum(rng.normal(0.0, 2e-4, (n, 2)), axis=0)
    head_heading = centre_heading + pan_rate * np.linspace(0.0, 0.1, n)
    return origin, head_heading, head_heading + theta, theta


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_cast_beams_agree_with_numpy(head: SensorParameters, seed: int) -> None:
    # Many obstacles and 700 beams per sweep: many blocks of beams, each with its own
    # candidate obstacles; one sweep's headings cross +-pi.
    rng = np.random.default_rng(seed)
    world = random_world(rng, 6, 25, 12)
    counts = np.zeros(3, dtype=int)  # seen, hidden, nothing hit
    for centre_heading in (0.3, math.pi, -2.0, rng.uniform(-math.pi, math.pi)):
        beams = sweep_beams(rng, 700, centre_heading, pan_rate=rng.uniform(-3.0, 3.0))
        expected = reference_beams(world, *beams, head)
        assert_same_beams(kernel_beams(world, *beams, head), expected)
        hit = np.isfinite(expected[0])
        counts += [np.sum(expected[1]), np.sum(hit & ~expected[1]), np.sum(~hit)]
    assert np.all(counts > 0), counts


def test_cast_beams_see_what_hides_only_the_return_path(head: SensorParameters) -> None:
    # A thin post just left of the head, outside every beam of the sweep's middle: it hides the
    # wall from the detector (a baseline to the left) for beams a degree or two left of
    # centre, though no beam comes near it.
    world = world_from_obstacles(
        walls=[([(2.0, -3.0), (2.0, 3.0)], 1.0)], cylinders=[((0.5, 0.085), 0.005, 1.0)]
    )
    n = 400
    theta = np.linspace(-math.radians(5), math.radians(5), n)
    origin, head_heading = np.zeros((n, 2)), np.zeros(n)
    got = kernel_beams(world, origin, head_heading, theta.copy(), theta, head)
    assert_same_beams(got, reference_beams(world, origin, head_heading, theta, theta, head))
    hidden = np.degrees(theta[~got[1]])
    assert hidden.size > 0 and np.all((hidden > 0.5) & (hidden < 3.0))
    assert np.all(got[4] == 0)  # every beam meets the wall


def test_cast_beams_across_plus_minus_pi(head: SensorParameters) -> None:
    # Beams straight behind: their headings cross pi while the obstacles' bearings (atan2)
    # jump from +pi to -pi. A wall of 5 cm pieces, so that each piece is a candidate of only
    # a few blocks.
    wall_y = np.linspace(-1.5, 1.5, 61)
    world = world_from_obstacles(walls=[(np.stack([np.full(61, -2.0), wall_y], 1), 1.0)])
    n = 700
    theta = np.linspace(-math.radians(20), math.radians(20), n)
    origin, head_heading = np.zeros((n, 2)), np.full(n, math.pi + 0.01)
    got = kernel_beams(world, origin, head_heading, head_heading + theta, theta, head)
    assert np.all(np.isfinite(got[0]))
    expected = reference_beams(world, origin, head_heading, head_heading + theta, theta, head)
    assert_same_beams(got, expected)


def test_cast_beams_from_far_apart_origins(head: SensorParameters) -> None:
    # Parallel beams from origins 2 m apart: posts off to the side of the origins' centre are
    # met by the beams from that side.
    n = 64
    origin = np.stack([np.zeros(n), np.linspace(-1.0, 1.0, n)], 1)
    posts = [((3.0, y), 0.02, 1.0) for y in (-0.9, 0.45, 0.93)]
    world = world_from_obstacles(walls=[([(5.0, -3.0), (5.0, 3.0)], 1.0)], cylinders=posts)
    beams = (origin, np.zeros(n), np.zeros(n), np.zeros(n))
    got = kernel_beams(world, *beams, head)
    assert_same_beams(got, reference_beams(world, *beams, head))
    assert set(got[4].tolist()) == {0, 1, 2, 3}


def test_cast_beams_shapes(head: SensorParameters) -> None:
    world = world_from_obstacles(walls=[([(2.0, -3.0), (2.0, 3.0)], 1.0)])
    theta = np.linspace(-0.2, 0.2, 3)
    beams = (np.zeros((3, 2)), np.zeros(3), theta.copy(), theta)
    got = kernel_beams(world, *beams, head)
    assert_same_beams(got, reference_beams(world, *beams, head))
    assert [a.dtype for a in got] == [np.float64, np.bool_, np.float64, np.float64, np.int64]
    empty = kernel_beams(world, np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0), head)
    assert all(a.shape == (0,) for a in empty)
