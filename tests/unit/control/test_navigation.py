"""The navigation field: cost-to-go without local minima, round what was seen."""

from __future__ import annotations

import numpy as np

from agent.control.controller import ControllerSettings
from agent.control.navigation import NavigationField
from agent.control.obstacles import Capsules
from agent.kinematics.vehicle import VehicleSpec
from tests.unit.control.test_safety import view


def u_shape() -> Capsules:
    """A U open toward −x (inner 1.6 m wide, 1.8 m deep) between the origin and a goal at
    (3.5, 0)."""
    a = np.array([[-0.6, 0.8], [1.2, 0.8], [1.2, -0.8]])
    b = np.array([[1.2, 0.8], [1.2, -0.8], [-0.6, -0.8]])
    return Capsules(a, b, np.zeros(3), np.full(3, 0.06), np.zeros(3, dtype=bool),
                    np.arange(3, dtype=np.int64))  # fmt: skip


def field_with_u() -> NavigationField:
    field = NavigationField(VehicleSpec(), ControllerSettings())
    field.fit(np.zeros(2), np.array([3.5, 0.0]))
    field.add_view(view(0.0, free_m=0.0), np.zeros(3), u_shape())
    assert field.update(0.0, np.array([3.5, 0.0]), 0.0, np.zeros(2))
    return field


def test_the_field_has_no_local_minimum_but_the_goal() -> None:
    field = field_with_u()
    C = field.cost_to_go
    assert C is not None
    padded = np.pad(C, 1, constant_values=np.inf)
    n_y, n_x = C.shape
    best = np.full(C.shape, np.inf)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                best = np.minimum(best, padded[1 + dy : 1 + dy + n_y, 1 + dx : 1 + dx + n_x])
    goal = np.unravel_index(np.argmin(C), C.shape)
    minima = np.argwhere(best >= C)
    assert [tuple(m) for m in minima] == [goal]


def test_from_inside_the_u_the_field_leads_out_of_its_mouth() -> None:
    field = field_with_u()
    # Inside the U the way to the goal is out of the open end, not through the closed one.
    assert abs(float(field.descent(np.array([[0.3, 0.0]]))[0])) > 0.5 * np.pi
    inside = field.value(np.array([[0.3, 0.0]]))[0]
    assert inside > 3.2 + 1.0  # well over the straight distance through the wall
    path = field.path(np.array([0.3, 0.0]), 3.0, 0.1)
    assert path[:, 0].min() < -0.5  # it leaves by the mouth, at x < -0.6 + margin


def test_the_map_remembers_obstacles_until_the_profile_sees_the_place_clear() -> None:
    field = field_with_u()
    assert field.occupied(0.0).sum() > 20
    # A later profile from inside the U looking at its closed end, clear to 2.5 m: the
    # closed end (1.2 m away) is seen clear (a wall gone) and leaves the map.
    before = field.occupied(1.0).sum()
    field.add_view(
        view(1.0, free_m=2.5), np.array([0.0, 0.0, 0.0]), u_shape().select(np.zeros(3, bool))
    )
    after = field.occupied(1.0).sum()
    assert after < before
