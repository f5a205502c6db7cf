"""The docking line's last approach against the memory of known clear space."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from agent.control.clearance import BLOCKED, CLEAR, UNSEEN, LocalState, look_ahead_row
from agent.control.docking import (
    DockTarget,
    dock_pose,
    line_clearance,
    refine_face,
    search_viewpoint,
)
from tests.unit.control.test_clearance import SETTINGS, SPEC, local_state


def face_state(face_x: float) -> np.ndarray:
    """The memory (80 × 80 cells of 5 cm from (−2, −2)) before a face at ``face_x``: clear
    up to 0.15 m short of it, unknown after, blocked from the face on."""
    x = -2.0 + 0.05 * (np.arange(80) + 0.5)
    row = np.where(x < face_x - 0.15, CLEAR, np.where(x < face_x, UNSEEN, BLOCKED))
    return np.tile(row, (80, 1)).astype(np.uint8)


def with_row(local: LocalState) -> LocalState:
    """``local`` as with a head that pans: forward motions keep the look-ahead row."""
    return replace(local, look_ahead_row=look_ahead_row(SPEC, SETTINGS))


def test_the_last_approach_reaches_the_stop_with_a_head_that_pans() -> None:
    """A face at x = 1 m, the stop 0.8 m before it (head 0.5 m from the face); the vehicle
    on the line 7 cm short. With the look-ahead row 0.3 m past the bumper it could not move
    (the row lies in the unknown cells next to the face); on the line the row stays
    ``dock_face_gap_m`` short of the face at the stop, and the vehicle can go on to it."""
    target = DockTarget(np.array([1.0, 0.0]), np.array([-1.0, 0.0]), 7)
    stop = dock_pose(target, 0.5, SPEC.head_offset_m)
    np.testing.assert_allclose(stop, [0.2, 0.0, 0.0], atol=1e-12)
    pose = np.array([0.13, 0.0, 0.0])
    plain = local_state(face_state(1.0))
    panning = with_row(plain)
    forward = np.array([0.15]), np.array([0.0])
    assert float(panning.free_travel(pose, *forward)[0]) < 0.01
    docking = line_clearance(panning, SPEC, SETTINGS, 0.5)
    assert docking.look_ahead_row is not None
    np.testing.assert_allclose(docking.look_ahead_row[:, 0], 0.4 + 0.4 - SETTINGS.dock_face_gap_m)
    np.testing.assert_array_equal(docking.look_ahead_row[:, 1], panning.look_ahead_row[:, 1])
    assert float(docking.free_travel(pose, *forward)[0]) > 0.07 + SETTINGS.stop_margin_m


def test_without_a_row_or_far_from_the_face_the_memory_is_left_as_it_is() -> None:
    plain = local_state(face_state(1.0))
    assert line_clearance(plain, SPEC, SETTINGS, 0.5) is plain
    panning = with_row(plain)
    assert line_clearance(panning, SPEC, SETTINGS, 2.0) is panning


def test_on_the_line_the_face_is_refined_its_centre_only_from_as_much_of_it() -> None:
    # Held: a face 0.4 m long along y through (2, 0), normal -x. A fresh vector sees it
    # turned by 2°, 1 cm nearer, and its centre 0.1 m along it, only 0.25 m of it (the part
    # of the plate seen from 0.5 m): the fresh normal and offset, the centre kept along it.
    held = DockTarget(np.array([2.0, 0.0]), np.array([-1.0, 0.0]), 7, 0.4)
    turn = math.radians(2.0)
    n = np.array([-math.cos(turn), math.sin(turn)])
    t = np.array([n[1], -n[0]])  # along the fresh face

    def refined(slide_m: float, length_m: float, ident: int = 7) -> DockTarget:
        fresh = DockTarget(held.centre_xy + 0.01 * n + slide_m * t, n, ident, length_m)
        return refine_face(held, fresh, math.radians(5.0), 0.05, 0.08)

    part = refined(0.1, 0.25)
    np.testing.assert_allclose(part.normal_xy, n)
    assert float((part.centre_xy - held.centre_xy) @ n) == pytest.approx(0.01, abs=1e-12)
    assert float((part.centre_xy - held.centre_xy) @ t) == pytest.approx(0.0, abs=1e-12)
    assert part.obstacle_id == 7 and part.length_m == 0.4
    # The whole face seen: its centre taken, 3 cm along; 0.1 m along (beyond 8 cm), not.
    whole = refined(0.03, 0.4)
    assert float((whole.centre_xy - held.centre_xy) @ t) == pytest.approx(0.03, abs=1e-12)
    far = refined(0.1, 0.4)
    assert float((far.centre_xy - held.centre_xy) @ t) == pytest.approx(0.0, abs=1e-12)
    # For the last of the line, only the face's offset along the held normal.
    fresh = DockTarget(held.centre_xy + 0.01 * n + 0.03 * t, n, 7, 0.4)
    last = refine_face(held, fresh, math.radians(5.0), 0.05, 0.08, hold_line=True)
    np.testing.assert_allclose(last.normal_xy, held.normal_xy)
    expected = held.centre_xy + float((fresh.centre_xy - held.centre_xy) @ held.normal_xy) * (
        held.normal_xy
    )
    np.testing.assert_allclose(last.centre_xy, expected, atol=1e-12)
    # Turned by 6°, moved 6 cm along its normal, or another face 0.3 m along: held.
    big = math.radians(6.0)
    turned = DockTarget(held.centre_xy, np.array([-math.cos(big), math.sin(big)]), 7, 0.4)
    moved = DockTarget(held.centre_xy + np.array([-0.06, 0.0]), held.normal_xy, 7, 0.4)
    along = DockTarget(held.centre_xy + 0.3 * t, n, 7, 0.4)
    for fresh in (turned, moved, along):
        assert refine_face(held, fresh, math.radians(5.0), 0.05, 0.08) is held
    # A new track of the plate: its id taken.
    assert refined(0.03, 0.4, ident=8).obstacle_id == 8


def test_the_search_goes_round_to_the_other_side_of_the_plate_s_wall() -> None:
    # A plate's goal on a wall along y (x = 0, from y = -3 to 3); searched from x = -1.4:
    # the next place is on the other side, square across the wall from the goal.
    wall = (np.array([[0.0, -3.0]]), np.array([[0.0, 3.0]]), np.array([0.1]))
    goal = np.array([0.02, 0.0])
    here = np.array([-1.38, 0.0])
    place = search_viewpoint(goal, 1.4, here[None], here, wall, keep_m=0.5)
    assert place is not None
    assert place[0] > 1.3 and abs(place[1]) < 1e-9
    # Searched from both sides: next square to the wall's line is in the wall; the places
    # left are those at 45 deg off the sides, a quarter turn round from both.
    both = np.array([here, place])
    third = search_viewpoint(goal, 1.4, both, place, wall, keep_m=0.5)
    assert third is not None
    bearing = math.degrees(math.atan2(third[1] - goal[1], third[0] - goal[0]))
    assert min(abs(abs(bearing) - 45.0), abs(abs(bearing) - 135.0)) < 1e-6
    assert third[0] > 0.0  # the nearer of them to where the vehicle is
    # Nothing clear on the circle: none.
    boxed = (np.array([[-5.0, 0.0]]), np.array([[5.0, 0.0]]), np.array([3.0]))
    assert search_viewpoint(goal, 1.4, here[None], here, boxed, keep_m=0.5) is None
