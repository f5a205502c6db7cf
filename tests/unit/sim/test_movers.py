"""Movers: kinematics, world-file entries, the simulator's view of them, seeded worldgen."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.errors import WorldFileError
from agent.kinematics.trajectory import StaticPose
from agent.sensor.params import simulated_head
from agent.sim import raycast, raycast_kernels
from agent.sim.movers import MOVER_GAP_M, Mover, mover_states, walks_apart
from agent.sim.simulator import SensorSimulator
from agent.sim.world import World
from agent.sim.world_file import load_world, parse_world
from agent.sim.worldgen import (
    TRACKING_CLEARANCE_M,
    TRACKING_SCENE_S,
    random_world,
    tracking_scene,
)
from tests.unit.sim.conftest import (
    EXAMPLE_WORLDS,
    TEST_WORLDS,
    check_single_line_error,
    closest_bodies,
)

# ============================================================================================
# Kinematics
# ============================================================================================
L_PATH = Mover(0.2, 0.8, np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 2.0]]), 0.5)  # 5 m, 20 s


def test_a_mover_walks_its_path_back_and_forth() -> None:
    t = np.array([0.0, 2.0, 6.0, 7.0, 10.0, 12.0, 16.0, 20.0, 22.0, -2.0])
    xy, vxy = L_PATH.states(t)
    expected_xy = [
        [0.0, 0.0], [1.0, 0.0], [3.0, 0.0], [3.0, 0.5], [3.0, 2.0],  # out, turning at 10 s
        [3.0, 1.0], [2.0, 0.0], [0.0, 0.0], [1.0, 0.0], [1.0, 0.0],  # back; period 20 s
    ]  # fmt: skip
    np.testing.assert_allclose(xy, expected_xy, atol=1e-12)
    np.testing.assert_allclose(vxy[1], [0.5, 0.0])  # out along the first leg
    np.testing.assert_allclose(vxy[3], [0.0, 0.5])  # out along the second
    np.testing.assert_allclose(vxy[5], [0.0, -0.5])  # back along the second
    np.testing.assert_allclose(vxy[6], [-0.5, 0.0])  # back along the first
    np.testing.assert_allclose(vxy[9], [-0.5, 0.0])  # before 0 it was coming back
    assert L_PATH.length_m == 5.0 and L_PATH.period_s == 20.0


def test_velocity_is_the_derivative_of_position() -> None:
    t = np.linspace(-30.0, 30.0, 601) + 0.0137  # away from the corners
    h = 1e-6
    xy, vxy = L_PATH.states(t)
    ahead, _ = L_PATH.states(t + h)
    np.testing.assert_allclose((ahead - xy) / h, vxy, atol=1e-6)
    np.testing.assert_allclose(np.hypot(*vxy.T), 0.5)


def test_mover_states_equal_each_movers_own_states_to_the_bit(rng: np.random.Generator) -> None:
    # The compiled pass (agent.sim.movers_kernels) against Mover.states, its numpy
    # reference: paths of 2-5 points, movers standing still, negative times, the Unix clock.
    for _ in range(50):
        movers = []
        for _ in range(int(rng.integers(1, 5))):
            points = int(rng.integers(2, 6))
            if rng.random() < 0.2:
                movers.append(Mover(0.2, 1.0, np.repeat(rng.uniform(-5, 5, (1, 2)), points, 0), 0))
            else:
                movers.append(Mover(0.2, 1.0, rng.uniform(-5, 5, (points, 2)), rng.uniform(0.1, 2)))
        t = np.concatenate([rng.uniform(-50, 200, 40), rng.uniform(1.7e9, 1.8e9, 5), [0.0]])
        xy, vxy = mover_states(movers, t)
        for j, mover in enumerate(movers):
            want_xy, want_vxy = mover.states(t)
            np.testing.assert_array_equal(xy[j], want_xy)
            np.testing.assert_array_equal(vxy[j], want_vxy)
        one_xy, one_vxy = mover_states(movers, float(t[0]))
        np.testing.assert_array_equal(one_xy, xy[:, 0])
        np.testing.assert_array_equal(one_vxy, vxy[:, 0])


def test_mover_states_shapes_and_a_large_clock() -> None:
    still = Mover(0.1, 1.0, np.array([[1.0, 2.0], [1.0, 2.0]]), 0.0)
    movers = [L_PATH, still]
    xy, vxy = mover_states(movers, 4.0)
    assert xy.shape == vxy.shape == (2, 2)
    np.testing.assert_allclose(xy, [[2.0, 0.0], [1.0, 2.0]])
    np.testing.assert_allclose(vxy[1], [0.0, 0.0])
    xy, vxy = mover_states(movers, np.arange(5.0))
    assert xy.shape == vxy.shape == (2, 5, 2)
    assert mover_states([], np.arange(3.0))[0].shape == (0, 3, 2)
    # The Unix clock (1.8e9 s = 9e7 periods): still placed to a micrometre.
    big = 1.8e9 + 4.0
    np.testing.assert_allclose(L_PATH.states(big)[0], [2.0, 0.0], atol=1e-6)
    with pytest.raises(ValueError, match="scalar or"):
        mover_states(movers, np.zeros((2, 2)))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"path": np.zeros((1, 2))}, "p >= 2"),
        ({"path": np.array([[0.0, 0.0], [math.nan, 1.0]])}, "finite"),
        ({"path": np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]])}, "equal neighbouring"),
        ({"path": np.zeros((2, 2))}, "speed must be 0"),
        ({"radius_m": 0.0}, "radius_m"),
        ({"reflectivity": -1.0}, "reflectivity"),
        ({"speed_m_s": -0.1}, "speed_m_s"),
    ],
)
def test_mover_refuses_bad_values(kwargs: dict[str, object], match: str) -> None:
    values: dict[str, object] = {
        "radius_m": 0.2, "reflectivity": 1.0, "path": np.array([[0.0, 0.0], [1.0, 0.0]]),
        "speed_m_s": 0.5,
    }  # fmt: skip
    values.update(kwargs)
    with pytest.raises(ValueError, match=match):
        Mover(**values)  # type: ignore[arg-type]


def test_mover_path_is_read_only_and_copied() -> None:
    path = np.array([[0.0, 0.0], [1.0, 0.0]])
    mover = Mover(0.2, 1.0, path, 0.5)
    path[0, 0] = 9.0
    assert mover.path[0, 0] == 0.0
    with pytest.raises(ValueError, match="read-only"):
        mover.path[0, 0] = 1.0


# ============================================================================================
# World files and worlds built in code
# ============================================================================================
MOVER_ENTRY = """
[[wall]]
points = [[3.0, -1.0], [3.0, 1.0]]
[[cylinder]]
center = [2.0, 0.5]
radius = 0.1
[[mover]]
radius = 0.2
reflectivity = 0.8
path = [[1.0, -1.0], [1.0, 1.5]]
speed = 0.4
"""


def test_movers_in_a_world_file_are_numbered_after_every_obstacle() -> None:
    world = parse_world(
        MOVER_ENTRY + "[[mover]]\nradius = 0.1\npath = [[0, 0], [1, 1]]\nspeed = 0\n"
    )
    assert world.n_obstacles == 2 and world.n_movers == 2
    np.testing.assert_array_equal(world.mover_ids, [2, 3])
    first = world.movers[0]
    assert (first.radius_m, first.reflectivity, first.speed_m_s) == (0.2, 0.8, 0.4)
    np.testing.assert_array_equal(first.path, [[1.0, -1.0], [1.0, 1.5]])
    assert world.movers[1].reflectivity == 1.0  # the default
    # A cut-down world keeps the movers and their ids.
    small = world.nearby((10.0, 10.0), 0.5)
    assert small.n_obstacles == 0 and small.movers == world.movers
    np.testing.assert_array_equal(small.mover_ids, [2, 3])


def test_crossing_world_loads() -> None:
    world = load_world(EXAMPLE_WORLDS / "crossing.toml")
    assert world.n_movers == 2 and world.vehicle_pose == (0.0, 0.0, 0.0)
    xy, _ = mover_states(world.movers, np.linspace(0.0, 30.0, 301))
    assert np.all((xy[..., 0] > 1.0) & (xy[..., 0] < 5.0))  # ahead of the start
    assert np.all(np.abs(xy[..., 1]) <= 1.2)  # inside the corridor


def test_movers_test_data_file() -> None:
    world = load_world(TEST_WORLDS / "movers.toml")
    assert world.n_movers == 3
    assert [m.speed_m_s for m in world.movers] == [0.4, 0.0, 3.0]


@pytest.mark.parametrize(
    ("entry", "fragments"),
    [
        ("radius = 0.2\npath = [[0, 0], [1, 0]]", ("[[mover]] 1", 'missing key "speed"')),
        ("speed = 0.2\npath = [[0, 0], [1, 0]]", ('missing key "radius"',)),
        ("radius = 0.2\nspeed = 0.2", ('missing key "path"',)),
        ("radius = 0.2\nspeed = 0.2\npath = [[0, 0], [1, 0]]\ncolour = 1", ("unknown key",)),
        ("radius = 0.2\nspeed = 3.5\npath = [[0, 0], [1, 0]]", ("speed must be from 0 to 3",)),
        ("radius = 0.2\nspeed = -1\npath = [[0, 0], [1, 0]]", ("speed must be from 0 to 3",)),
        ("radius = 0.2\nspeed = true\npath = [[0, 0], [1, 0]]", ("speed must be a finite",)),
        ("radius = 0\nspeed = 0.2\npath = [[0, 0], [1, 0]]", ("radius must be a finite positive",)),
        ("radius = 2000.0\nspeed = 0.2\npath = [[0, 0], [1, 0]]", ("radius must be from",)),
        ("radius = 0.2\nspeed = 0.2\npath = [[0, 0]]", ("at least 2 points",)),
        ("radius = 0.2\nspeed = 0.2\npath = 3", ("path must be a list",)),
        ("radius = 0.2\nspeed = 0.2\npath = [[0, 0], [1, 'a']]", ("point 2 of path",)),
        ("radius = 0.2\nspeed = 0.2\npath = [[0, 0], [1, 0], [1, 0]]", ("points 2 and 3",)),
        ("radius = 0.2\nspeed = 0.2\npath = [[1, 1], [1, 1]]", ("zero length", "speed 0")),
        ("radius = 0.2\nspeed = 0.2\npath = [[0, 0], [1e4, 0]]", ("point 2 of path", "1000 m")),
        ("radius = 0.2\nspeed = 0.2\npath = [[0, 0], [1, 0]]\nreflectivity = 0",
         ("reflectivity",)),
    ],
)  # fmt: skip
def test_bad_mover_entries_name_the_entry_and_key(entry: str, fragments: tuple[str, ...]) -> None:
    path = Path("w.toml")
    with pytest.raises(WorldFileError) as info:
        parse_world("[[mover]]\n" + entry + "\n", path)
    check_single_line_error(info.value, path, "[[mover]] 1", *fragments)


def test_mover_limits() -> None:
    many = "".join(
        "[[mover]]\nradius = 0.1\nspeed = 0\npath = [[0, 0], [1, 0]]\n" for _ in range(65)
    )
    with pytest.raises(WorldFileError, match="65 movers is more than the limit of 64"):
        parse_world(many)
    long = "[[mover]]\nradius = 0.1\nspeed = 0.1\npath = [" + ", ".join(
        f"[{i}, 0]" for i in range(129)
    ) + "]\n"  # fmt: skip
    with pytest.raises(WorldFileError, match="129 points in path is more than the limit of 128"):
        parse_world(long)
    with pytest.raises(WorldFileError, match="mover must be an array of tables"):
        parse_world("mover = 3\n")


def test_world_build_takes_movers_as_tuples_or_instances() -> None:
    world = World.build(
        cylinders=[((1.0, 0.0), 0.1, 1.0)],
        movers=[(np.array([[0.0, 1.0], [2.0, 1.0]]), 0.2, 0.5, 0.9), L_PATH],
    )
    assert world.movers[1] is L_PATH and world.movers[0].speed_m_s == 0.5
    np.testing.assert_array_equal(world.mover_ids, [1, 2])
    with pytest.raises(WorldFileError, match=r"\[\[mover\]\] 1: speed must be from 0 to 3"):
        World.build(movers=[(np.array([[0.0, 1.0], [2.0, 1.0]]), 0.2, 5.0, 0.9)])
    with pytest.raises(WorldFileError, match=r"\[\[mover\]\] 1: must be a tuple"):
        World.build(movers=[(0.2, 0.5)])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="mover_id_base"):
        World(**{**_arrays(world), "obstacles": world.obstacles, "mover_id_base": 0})


def _arrays(world: World) -> dict[str, Any]:
    names = (
        "segments_start", "segments_end", "segments_reflectivity", "segments_obstacle",
        "circles_center", "circles_radius", "circles_reflectivity", "circles_obstacle",
    )  # fmt: skip
    return {name: getattr(world, name) for name in names}


# ============================================================================================
# The simulator sees movers
# ============================================================================================
HEAD = simulated_head()
SWEEP_START_S = 100.0


def _hit_points(truth: object) -> np.ndarray:
    origin, heading, rng = truth.beam_origin_xy, truth.beam_heading_rad, truth.range_m  # type: ignore[attr-defined]
    return np.asarray(origin + rng[:, None] * np.stack([np.cos(heading), np.sin(heading)], 1))


def test_a_mover_is_placed_at_each_samples_time_and_smeared() -> None:
    # A fast mover crossing the beam 1 m ahead: 3 m/s moves it 0.3 m during the sweep.
    mover = Mover(0.15, 1.0, np.array([[1.0, -1.5], [1.0, 1.5]]), 3.0)
    world = World.build(walls=[(((2.5, -2.0), (2.5, 2.0)), 1.0)], movers=[mover])
    sim = SensorSimulator(world, HEAD, np.random.default_rng(1))
    pose = StaticPose(-HEAD.mount_offset_m, 0.0, 0.0)  # centre of scanning at the origin
    # At 100.5 s (mod its 2 s period) it crosses y = 0 going left: mid-sweep.
    _, truth = sim.sweep(start_time_s=SWEEP_START_S + 0.45, trajectory=pose)
    on_mover = truth.obstacle == world.mover_ids[0]
    assert on_mover.sum() >= 10
    points = _hit_points(truth)[on_mover]
    times = truth.beam_time_s[on_mover]
    centres, _ = mover.states(times)
    # Every hit lies on the mover's circle where it was at that sample's time ...
    np.testing.assert_allclose(np.hypot(*(points - centres).T), mover.radius_m, atol=1e-9)
    # ... and not where it was at the first hit's time (it moved centimetres meanwhile).
    first_centre, _ = mover.states(times[0])
    late = np.abs(np.hypot(*(points[-3:] - first_centre).T) - mover.radius_m)
    assert np.all(late > 0.01)
    # Samples off the mover see the wall behind, or nothing.
    assert set(np.unique(truth.obstacle[~on_mover]).tolist()) <= {-1, 0}


def test_a_mover_hides_what_is_behind_it_and_walls_hide_movers() -> None:
    in_front = Mover(0.2, 1.0, np.array([[1.0, 0.0], [1.0, 0.0]]), 0.0)
    behind = Mover(0.2, 1.0, np.array([[2.0, 0.0], [2.0, 0.0]]), 0.0)
    wall = (((1.5, -2.0), (1.5, 2.0)), 1.0)
    world = World.build(walls=[wall], movers=[in_front, behind])
    sim = SensorSimulator(world, HEAD, np.random.default_rng(2))
    pose = StaticPose(-HEAD.mount_offset_m, 0.0, 0.0)
    _, truth = sim.sweep(start_time_s=SWEEP_START_S, trajectory=pose)
    ids = set(np.unique(truth.obstacle).tolist())
    assert int(world.mover_ids[0]) in ids and 0 in ids  # the front mover and the wall
    assert int(world.mover_ids[1]) not in ids  # behind the wall
    on_front = truth.obstacle == world.mover_ids[0]
    np.testing.assert_allclose(truth.range_m[on_front].min(), 0.8, atol=1e-3)


def test_a_mover_blocks_the_return_path_to_the_detector() -> None:
    # A beam along +x from the origin meets the wall at 2 m; the detector sees the spot from
    # d = 0.095 m to the left. A thin mover near the return path (not on the beam) blocks it.
    world = World.build(walls=[(((2.0, -1.0), (2.0, 1.0)), 1.0)])
    segments, circles = raycast.world_tables(world)
    movers = np.array([[0.03, 1.0, 1.0]])  # radius, reflectivity, id

    def beam(centre_y: float) -> tuple[float, bool, int]:
        r, visible, _, _, obstacle = raycast_kernels.cast_beams_moving(
            np.zeros((1, 2)), np.zeros(1), np.zeros(1), np.zeros(1), 6.0, 0.095, 0.0,
            HEAD.scan_half_angle_rad, 1e-6, segments, circles,
            np.array([[[1.0, centre_y]]]), movers,
        )  # fmt: skip
        return float(r[0]), bool(visible[0]), int(obstacle[0])

    assert beam(0.3) == (2.0, True, 0)  # far from both paths
    assert beam(0.07) == (2.0, False, 0)  # on the return path only: the spot is hidden
    r, _visible, obstacle = beam(0.0)  # on the beam: the mover is hit
    assert obstacle == 1 and r == pytest.approx(0.97)


def test_a_mover_out_of_reach_changes_nothing() -> None:
    # The moving kernel gives the static world's answer bit for bit where no mover is met.
    walls = [(((2.0, -2.0), (2.0, 2.0)), 1.0)]
    cylinders = [((1.2, 0.3), 0.1, 1.5)]
    far = Mover(0.2, 1.0, np.array([[-20.0, 0.0], [-20.0, 5.0]]), 0.5)
    static = World.build(walls=walls, cylinders=cylinders)
    moving = World.build(walls=walls, cylinders=cylinders, movers=[far])
    pose = StaticPose(0.0, 0.1, 0.2)
    out = []
    for world in (static, moving):
        sim = SensorSimulator(world, HEAD, np.random.default_rng(3))
        raw, truth = sim.sweep(start_time_s=SWEEP_START_S, trajectory=pose, pan_rad=0.3)
        out.append((raw, truth))
    (raw_a, truth_a), (raw_b, truth_b) = out
    np.testing.assert_array_equal(raw_a.current_1_A, raw_b.current_1_A)
    np.testing.assert_array_equal(raw_a.current_2_A, raw_b.current_2_A)
    np.testing.assert_array_equal(truth_a.range_m, truth_b.range_m)
    np.testing.assert_array_equal(truth_a.obstacle, truth_b.obstacle)


# ============================================================================================
# Random worlds
# ============================================================================================
def test_random_world_without_movers_is_unchanged_and_movers_are_seeded() -> None:
    plain = random_world(np.random.default_rng(5), 20)
    again = random_world(np.random.default_rng(5), 20, n_movers=0)
    np.testing.assert_array_equal(plain.segments_start, again.segments_start)
    assert plain.vehicle_pose == again.vehicle_pose and plain.name == "random 20 obstacles"
    a = random_world(np.random.default_rng(5), 20, n_movers=3, mover_speed_m_s=(0.3, 0.5))
    b = random_world(np.random.default_rng(5), 20, n_movers=3, mover_speed_m_s=(0.3, 0.5))
    np.testing.assert_array_equal(a.segments_start, plain.segments_start)  # drawn after
    assert a.vehicle_pose == plain.vehicle_pose
    assert a.n_movers == 3
    for ma, mb in zip(a.movers, b.movers, strict=True):
        np.testing.assert_array_equal(ma.path, mb.path)
        assert 0.3 <= ma.speed_m_s == mb.speed_m_s <= 0.5
    with pytest.raises(ValueError, match="mover_speed_m_s"):
        random_world(np.random.default_rng(5), 20, n_movers=1, mover_speed_m_s=(0.5, 0.3))


def test_walks_apart_refuses_movers_that_pass_through_each_other() -> None:
    # Two walkers on one line towards each other meet in the middle at t = 2.5 s.
    east = Mover(radius_m=0.2, reflectivity=1.0, path=((0.0, 0.0), (5.0, 0.0)), speed_m_s=1.0)
    west = Mover(radius_m=0.2, reflectivity=1.0, path=((5.0, 0.0), (0.0, 0.0)), speed_m_s=1.0)
    assert not walks_apart([east], west)
    assert walks_apart([east], west, horizon_s=2.0)  # they have not met yet
    # A parallel lane: bodies 0.6 - 0.4 = 0.2 m apart, enough for a 0.1 m gap, not 0.3 m.
    beside = Mover(radius_m=0.2, reflectivity=1.0, path=((5.0, 0.6), (0.0, 0.6)), speed_m_s=1.0)
    assert walks_apart([east], beside) and not walks_apart([east], beside, gap_m=0.3)
    # Crossing lanes, apart only when their timing keeps them so: the second walker
    # reaches the crossing (2.5, 0) at 2.5 s as well, unless it is slower.
    north = Mover(radius_m=0.2, reflectivity=1.0, path=((2.5, -2.5), (2.5, 2.5)), speed_m_s=1.0)
    slow = Mover(radius_m=0.2, reflectivity=1.0, path=((2.5, -2.5), (2.5, 2.5)), speed_m_s=0.5)
    assert not walks_apart([east], north, horizon_s=10.0)
    # The slow one is at the crossing at 5, 15, 25 ... s, when east is at its far end.
    assert walks_apart([east], slow)
    assert walks_apart([], north)


def test_generated_movers_never_pass_through_one_another() -> None:
    seen = 0
    for seed in range(40):
        world, _ = tracking_scene(np.random.default_rng([0, seed]), n_movers=3)
        assert closest_bodies(world.movers, TRACKING_SCENE_S) >= MOVER_GAP_M - 0.02
        seen += world.n_movers >= 2
        crowd = random_world(np.random.default_rng(seed), 5, room_m=8.0, n_movers=3)
        assert closest_bodies(crowd.movers) >= MOVER_GAP_M - 0.02
    assert seen >= 30


def _path_distance(points: np.ndarray, path: np.ndarray) -> np.ndarray:
    """Distances from points (q, 2) to the polyline path (k, 2)."""
    a, b = path[:-1], path[1:]
    e = b - a
    t = np.clip(np.einsum("qsd,sd->qs", points[:, None] - a, e) / np.einsum("sd,sd->s", e, e), 0, 1)
    nearest = a + t[..., None] * e
    return np.asarray(np.hypot(*(points[:, None] - nearest).transpose(2, 0, 1)).min(axis=1))


def _outline_points(world: World) -> np.ndarray:
    """Points every 1 cm on every static surface."""
    pts = []
    for a, b in zip(world.segments_start, world.segments_end, strict=True):
        n = max(2, math.ceil(float(np.hypot(*(b - a))) / 0.01))
        pts.append(a + np.linspace(0, 1, n)[:, None] * (b - a))
    for c, r in zip(world.circles_center, world.circles_radius, strict=True):
        ang = np.linspace(0, 2 * math.pi, 200)
        pts.append(c + r * np.stack([np.cos(ang), np.sin(ang)], 1))
    return np.concatenate(pts)


def test_tracking_scenes_are_seeded_and_keep_their_promises() -> None:
    within_range = []
    movers_seen = set()
    for seed in range(12):
        world, path = tracking_scene(np.random.default_rng(seed))
        again, path_again = tracking_scene(np.random.default_rng(seed))
        np.testing.assert_array_equal(path, path_again)
        np.testing.assert_array_equal(world.segments_start, again.segments_start)
        np.testing.assert_array_equal(world.circles_center, again.circles_center)
        assert [m.speed_m_s for m in world.movers] == [m.speed_m_s for m in again.movers]
        # The path: starts at the vehicle, facing its first leg, 8-15 m long.
        assert path.ndim == 2 and path.shape[1] == 2 and path.shape[0] >= 3
        np.testing.assert_allclose(path[0], world.vehicle_pose[:2])
        first = path[1] - path[0]
        assert math.atan2(first[1], first[0]) == pytest.approx(world.vehicle_pose[2])
        assert 8.0 <= float(np.hypot(*np.diff(path, axis=0).T).sum()) <= 15.0
        # Static obstacles keep their clearance (1 cm sampling of the outlines).
        gaps = _path_distance(_outline_points(world), path)
        assert gaps.min() >= TRACKING_CLEARANCE_M - 0.01
        # What is not the room is mostly within the sensor's reach of the path.
        inner = world.segments_obstacle != 0
        centres = np.concatenate(
            [0.5 * (world.segments_start[inner] + world.segments_end[inner]),
             world.circles_center]
        )  # fmt: skip
        within_range.append(np.mean(_path_distance(centres, path) <= 2.5))
        # Movers: 0-3, 0.2-0.8 m/s, crossing the path.
        assert 0 <= world.n_movers <= 3
        movers_seen.add(world.n_movers)
        for mover in world.movers:
            assert 0.2 <= mover.speed_m_s <= 0.8
            walk = mover.states(np.linspace(0.0, mover.period_s, 400))[0]
            assert _path_distance(walk, path).min() < 0.05
    assert np.mean(within_range) > 0.8
    assert len(movers_seen) >= 3
    world, _ = tracking_scene(np.random.default_rng(0), n_movers=2)
    assert world.n_movers == 2
    with pytest.raises(ValueError, match="n_movers"):
        tracking_scene(np.random.default_rng(0), n_movers=-1)
