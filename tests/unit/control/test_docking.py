"""The docking line's last approach against the memory of known clear space."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from agent.control.clearance import BLOCKED, CLEAR, UNSEEN, LocalState, look_ahead_row
from agent.control.docking import DockTarget, dock_pose, line_clearance
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
