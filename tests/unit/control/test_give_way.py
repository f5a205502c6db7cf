"""Giving way to walkers (agent.control.give_way): out of a coming walker's walk in time,
or standing."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from agent.control.clearance import BAND, BLOCKED, CLEAR, LocalState
from agent.control.controller import Controller
from agent.control.geometry import from_pose, outline_perimeter
from agent.control.give_way import Walkers, arrival_s, walk_danger, walk_depth, way_out
from agent.control.local_planner import ArcPlanner
from agent.control.navigation import NavigationField
from agent.control.settings import ControllerSettings
from agent.kinematics.vehicle import VehicleSpec
from agent.task import Task
from tests.unit.control.test_clearance import local_state
from tests.unit.control.test_safety import NO_LOOK, odometry, view

SPEC = VehicleSpec()
SETTINGS = ControllerSettings()
OUTLINE = outline_perimeter(SPEC, SETTINGS.outline_spacing_m)


def _local(state: np.ndarray) -> LocalState:
    """The local state about the origin (:func:`local_state`), a mover's capsule reaching
    the vehicle (what calls for a way out)."""
    return replace(local_state(state), mover_intrudes=True)


def _walker(x: float, y: float, vx: float, vy: float, r: float = 0.2, age: float = 0.0) -> Walkers:
    return Walkers(np.array([[x, y]]), np.array([[vx, vy]]), np.array([r]), np.array([age]), 0.0)


def _here(pose: np.ndarray) -> np.ndarray:
    return np.stack(from_pose(pose, OUTLINE[:, 0], OUTLINE[:, 1]), axis=1)


def test_the_depth_is_the_way_to_either_side_of_the_walk() -> None:
    """The vehicle at the origin facing +x (front at x = 0.4); a walker of radius 0.2 walks
    the line x = 0.5 along y: the walk (with the 0.15 m margin) reaches x = 0.15, so the
    vehicle is 0.25 m in; a walk along x through the origin needs 0.65 m either way."""
    here = _here(np.zeros(3))
    across = walk_depth(here, _walker(0.5, -2.0, 0.0, 0.5), 0.15)
    assert across[0] == pytest.approx(0.25)
    along = walk_depth(here, _walker(-3.0, 0.0, 0.5, 0.0), 0.15)
    assert along[0] == pytest.approx(0.3 + 0.35)
    beside = walk_depth(here, _walker(1.0, -2.0, 0.0, 0.5), 0.15)
    assert beside[0] == 0.0


def test_a_walker_comes_along_its_velocity_and_a_remembered_one_either_way() -> None:
    here = _here(np.zeros(3))
    # 2 m to go to the outline's side at y = -0.3, less its radius: 1.5 m at 0.5 m/s.
    assert arrival_s(here, _walker(0.3, -2.0, 0.0, 0.5), 0.15)[0] == pytest.approx(3.0)
    assert math.isinf(arrival_s(here, _walker(0.3, -2.0, 0.0, -0.5), 0.15)[0])
    # Remembered 1 s ago walking away: it may have turned back and come 0.5 m nearer.
    remembered = arrival_s(here, _walker(0.3, -2.0, 0.0, -0.5, age=1.0), 0.15)[0]
    assert remembered == pytest.approx(2.0)
    # Its centre already past the near side: over the outline now.
    assert arrival_s(here, _walker(0.3, 0.0, 0.0, 0.5), 0.15)[0] == 0.0


def test_a_vehicle_across_a_crossing_walk_backs_out_of_it_in_time() -> None:
    """The walker crosses just in front of the bumper, 3 s away: the way out is back, out
    of its walk before it comes, and the vehicle's outline is then beside the walk."""
    local = _local(np.full((80, 80), CLEAR, dtype=np.uint8))
    walker = _walker(0.5, -2.0, 0.0, 0.5)
    way = way_out(np.zeros(3), OUTLINE, walker, local, SPEC, SETTINGS)
    assert way is not None
    assert way.v_unit < 0.0
    assert way.time_s <= 3.0 - SETTINGS.give_way_reserve_s
    assert 0.25 <= way.distance_m <= 0.45


def test_no_way_out_through_unknown_space_nor_when_too_late() -> None:
    state = np.full((80, 80), CLEAR, dtype=np.uint8)
    state[:, :31] = BAND  # nothing known clear 5 cm behind the rear bumper (x < -0.45)
    state[:, 50:] = BLOCKED  # nor ahead of x = 0.5
    local = _local(state)
    assert (
        way_out(np.zeros(3), OUTLINE, _walker(0.5, -2.0, 0.0, 0.5), local, SPEC, SETTINGS) is None
    )
    free = _local(np.full((80, 80), CLEAR, dtype=np.uint8))
    # 0.5 m away at 0.5 m/s: it is there in 0.6 s, before any way out is done.
    late = _walker(0.5, -0.8, 0.0, 0.5)
    assert way_out(np.zeros(3), OUTLINE, late, free, SPEC, SETTINGS) is None


def test_out_of_the_walk_or_far_along_it_the_vehicle_stands() -> None:
    """Beside the walk, or a walker beyond the horizon along it, it stands; a walker
    walking away near it may turn back (the worlds' walkers do, at their walk's end): the
    vehicle leaves that walk as well."""
    free = _local(np.full((80, 80), CLEAR, dtype=np.uint8))
    beside = _walker(1.0, -2.0, 0.0, 0.5)
    assert way_out(np.zeros(3), OUTLINE, beside, free, SPEC, SETTINGS) is None
    far = _walker(0.5, -4.0, 0.0, -0.5)  # 3.5 m to go: 7 s
    assert way_out(np.zeros(3), OUTLINE, far, free, SPEC, SETTINGS) is None
    away = _walker(0.5, -2.0, 0.0, -0.5)
    assert way_out(np.zeros(3), OUTLINE, away, free, SPEC, SETTINGS) is not None


def test_a_walker_along_the_axis_is_not_backed_away_from() -> None:
    """Head-on along the vehicle's axis: backing straight never leaves the walk, nor does
    any motion within 1 m (the outline must move 0.65 m sideways): the vehicle stands,
    rather than backing until the walker catches it up."""
    free = _local(np.full((80, 80), CLEAR, dtype=np.uint8))
    for x in (2.0, 3.0):
        assert (
            way_out(np.zeros(3), OUTLINE, _walker(x, 0.0, -0.5, 0.0), free, SPEC, SETTINGS) is None
        )


def test_a_walker_through_the_middle_is_outrun_ahead_when_there_is_time() -> None:
    """Across the vehicle's middle, 3 s away: 0.75 m on (the rear bumper out past the walk)
    takes 2.5 s from rest to rest, within the 0.5 s reserve."""
    free = _local(np.full((80, 80), CLEAR, dtype=np.uint8))
    way = way_out(np.zeros(3), OUTLINE, _walker(0.0, -2.0, 0.0, 0.5), free, SPEC, SETTINGS)
    assert way is not None
    assert (way.v_unit, way.w_unit, way.distance_m) == (1.0, 0.0, pytest.approx(0.75))
    assert way.time_s == pytest.approx(2.5)
    assert (way.speed_m_s, way.yaw_rate_rad_s) == (SPEC.max_speed_m_s, 0.0)


def test_walkers_in_the_vector_walk_on_and_remembered_ones_age() -> None:
    w = Walkers(np.array([[0.0, 0.0], [1.0, 1.0]]), np.array([[0.5, 0.0], [0.0, 0.5]]),
                np.array([0.2, 0.2]), np.array([0.0, 1.0]), 10.0)  # fmt: skip
    later = w.at(12.0)
    np.testing.assert_allclose(later.position, [[1.0, 0.0], [1.0, 1.0]])
    np.testing.assert_allclose(later.age, [0.0, 3.0])


def test_a_walk_is_a_danger_while_its_walker_may_come_before_the_vehicle_could_leave() -> None:
    """Outlines at three poses against a walker crossing x = 0.5: the outline across its
    walk (0.25 m in: 1.41 s to leave from rest, 1.91 s with the reserve) is in danger while
    the walker may come (either way) within that plus the lead; beside the walk, never."""
    poses = np.array([[0.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, math.pi / 2.0]])
    points = np.stack([_here(p) for p in poses])  # (3, p, 2)
    leave = 2.0 * math.sqrt(0.25 / SPEC.max_accel_m_s2) + SETTINGS.give_way_reserve_s
    near = _walker(0.5, -1.5, 0.0, 0.5)  # 1.0 m to go: 2 s
    danger = walk_danger(points, near, SPEC, SETTINGS, 0.5)
    assert leave + 0.5 > 2.0 and danger[0] == pytest.approx(0.25)
    assert danger[1] == 0.0
    assert danger[2] == pytest.approx(walk_depth(points[2], near, 0.15)[0])
    # Walking away, it may still turn back: as near, as dangerous.
    away = walk_danger(points, _walker(0.5, -1.5, 0.0, -0.5), SPEC, SETTINGS, 0.5)
    np.testing.assert_array_equal(away, danger)
    # With no lead, 2 s off is time enough to leave.
    assert walk_danger(points, near, SPEC, SETTINGS, 0.0)[0] == 0.0
    assert walk_danger(points, Walkers.none(), SPEC, SETTINGS, 1.0).shape == (3,)


def test_a_walker_walking_on_to_its_walks_far_end_comes_back_only_from_there() -> None:
    """Walking away (along -y, 1.7 m past the outline's side at y = -0.3), a walker whose
    walk was seen to reach 1.0 m further that way walks there and back before it can come:
    (1.0 + 1.0 + 1.7 - 0.2) m at 0.5 m/s, 7 s, not the 3 s of one that may turn at once;
    its danger goes with it."""
    here = _here(np.zeros(3))
    turns_now = _walker(0.3, -2.0, 0.0, -0.5)
    walks_on = replace(turns_now, onward=np.array([1.0]))
    assert arrival_s(here, turns_now, 0.15, either_way=True)[0] == pytest.approx(3.0)
    assert arrival_s(here, walks_on, 0.15, either_way=True)[0] == pytest.approx(7.0)
    # Coming toward the vehicle, how far it walks on beyond changes nothing.
    coming = _walker(0.3, -2.0, 0.0, 0.5)
    on = arrival_s(here, replace(coming, onward=np.array([1.0])), 0.15, either_way=True)
    assert on[0] == pytest.approx(arrival_s(here, coming, 0.15, either_way=True)[0])
    # Walked on for 1 s, 0.5 m of it is left.
    assert walks_on.at(1.0).onward_m[0] == pytest.approx(0.5)
    poses = np.array([[0.0, 0.0, 0.0]])
    points = np.stack([_here(p) for p in poses])
    lead = 2.5
    assert walk_danger(points, turns_now, SPEC, SETTINGS, lead)[0] > 0.0
    assert walk_danger(points, walks_on, SPEC, SETTINGS, lead)[0] == 0.0


def test_beyond_the_end_its_walker_was_seen_to_turn_at_a_walk_holds_no_danger() -> None:
    """A walker on the line x = 0.5 (the vehicle at the origin is 0.25 m in its walk) that
    turns 1.0 m short of the outline (its walk ends at y = -1.5, its centre 0.5 m on from
    y = -2.0): the outline is out of its walk, never met, in no danger; the same walker
    with its walk's end unknown (or beyond the outline) is as before."""
    here = _here(np.zeros(3))
    open_ended = _walker(0.5, -2.0, 0.0, 0.5)
    short = replace(open_ended, span=np.array([[-1.0, 0.5]]))
    assert walk_depth(here, open_ended, 0.15)[0] == pytest.approx(0.25)
    assert walk_depth(here, short, 0.15)[0] == 0.0
    assert math.isinf(arrival_s(here, short, 0.15, either_way=True)[0])
    assert walk_danger(here[None], short, SPEC, SETTINGS, 5.0)[0] == 0.0
    through = replace(open_ended, span=np.array([[-1.0, 3.0]]))
    assert walk_depth(here, through, 0.15)[0] == pytest.approx(0.25)
    assert arrival_s(here, through, 0.15)[0] == pytest.approx(arrival_s(here, open_ended, 0.15)[0])
    # Its span walks with it: 1 s on, its centre may go 0.5 m less far ahead.
    np.testing.assert_allclose(short.at(1.0).span_m, [[-1.5, 0.0]])
    # Its body reaches its radius past its centre's end: an outline 0.1 m beyond it is met.
    reaches = replace(open_ended, span=np.array([[-1.0, 1.6]]))
    assert walk_depth(here, reaches, 0.15)[0] == pytest.approx(0.25)


def _open_field(goal: tuple[float, float]) -> NavigationField:
    field = NavigationField(SPEC, SETTINGS)
    field.fit(np.zeros(2), np.array(goal))
    no_obstacles = local_state(np.zeros((1, 1))).intruders
    field.add_view(view(0.0, free_m=2.5), np.zeros(3), no_obstacles)
    assert field.update(0.0, np.array(goal), 0.0, np.zeros(2))
    return field


def test_the_planner_waits_beside_a_walk_rather_than_in_it() -> None:
    """All clear, the goal 3.5 m ahead: the planner drives straight on, its arc ending with
    the bumper 1.15 m out. A walker on a line crossing 1.2 m ahead, 1.6 m off it, makes that
    end lie in its walk (from 0.85 m) too near to leave before it may come, walking either
    way: the chosen arc ends out of it. 4 m off, the walk is no danger."""
    planner = ArcPlanner(SPEC, SETTINGS)
    local = local_state(np.full((80, 80), CLEAR, dtype=np.uint8))
    field = _open_field((3.5, 0.0))
    free = planner.choose(np.zeros(3), local, field, 0.1)
    assert free.speed_m_s > 0.4 and free.rollout_xy[-1, 0] > 0.5
    for vy in (0.6, -0.6):
        walker = _walker(1.2, -1.9, 0.0, vy)
        waits = planner.choose(np.zeros(3), local, field, 0.1, walkers=walker)
        end, before = waits.rollout_xy[-1], waits.rollout_xy[-2]
        yaw = math.atan2(*(end - before)[::-1]) if np.hypot(*(end - before)) > 1e-9 else 0.0
        at_end = _here(np.array([end[0], end[1], yaw]))
        assert walk_danger(at_end, walker, SPEC, SETTINGS, SETTINGS.horizon_s) == 0.0
        assert walk_depth(_here(np.array([0.75, 0.0, 0.0])), walker, 0.15)[0] > 0.0
    far = planner.choose(np.zeros(3), local, field, 0.1, walkers=_walker(1.2, -4.3, 0.0, 0.6))
    assert far.speed_m_s == free.speed_m_s and far.yaw_rate_rad_s == free.yaw_rate_rad_s


def test_the_controller_leaves_a_walk_before_the_walkers_capsule_reaches_it() -> None:
    """Standing with the bumper 0.15 m into the walk of a walker 2.3 s off (its capsule,
    1.5 s of walk, still 0.4 m short of the vehicle): the vehicle backs out of the walk
    ("giving_way") rather than driving on toward its goal across it."""
    ctl = Controller(Task("goto", (5.0, 0.0)), settings=NO_LOOK)
    odometry(ctl, 0.0)
    base = view(0.0)
    cov = np.diag([1e-4, 1e-4, 1e-4, 1e-4])[None]
    walker = replace(
        base, obstacle_id=np.array([7]), kind=np.array([3], dtype=np.uint8),
        position_xy=np.array([[0.6, -1.9]]), velocity_xy=np.array([[0.0, 0.6]]),
        covariance=cov, extent=np.array([[0.2, 0.0, 0.0, 0.0]]), reflectivity=np.array([0.5]),
    )  # fmt: skip
    ctl.update_environment(walker)
    out = ctl.command(0.05)
    assert out.reason == "giving_way" and out.speed_m_s < 0.0
    # Without the walker it drives on.
    calm = Controller(Task("goto", (5.0, 0.0)), settings=NO_LOOK)
    odometry(calm, 0.0)
    calm.update_environment(base)
    assert calm.command(0.05).speed_m_s > 0.0
