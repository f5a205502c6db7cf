"""Giving way to walkers (agent.control.give_way): out of a coming walker's walk in time,
or standing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.control.clearance import BAND, BLOCKED, CLEAR, LocalState
from agent.control.geometry import from_pose, outline_perimeter
from agent.control.give_way import Walkers, arrival_s, walk_depth, way_out
from agent.control.obstacles import Capsules
from agent.control.settings import ControllerSettings
from agent.kinematics.vehicle import VehicleSpec

SPEC = VehicleSpec()
SETTINGS = ControllerSettings()
OUTLINE = outline_perimeter(SPEC, SETTINGS.outline_spacing_m)


def _local(state: np.ndarray) -> LocalState:
    empty = Capsules(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0),
                     np.zeros(0, dtype=bool), np.zeros(0, dtype=np.int64))  # fmt: skip
    return LocalState(
        origin_xy=np.array([-2.0, -2.0]), cell_m=0.05, state=state.astype(np.uint8),
        intruders=empty, mover_intrudes=True, spec=SPEC, settings=SETTINGS,
    )  # fmt: skip


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


def test_out_of_the_walk_or_walking_away_the_vehicle_stands() -> None:
    free = _local(np.full((80, 80), CLEAR, dtype=np.uint8))
    beside = _walker(1.0, -2.0, 0.0, 0.5)
    assert way_out(np.zeros(3), OUTLINE, beside, free, SPEC, SETTINGS) is None
    away = _walker(0.5, -2.0, 0.0, -0.5)
    assert way_out(np.zeros(3), OUTLINE, away, free, SPEC, SETTINGS) is None


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
