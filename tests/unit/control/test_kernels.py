"""The compiled kernels of the command's hot path against their numpy references, on random
inputs: equal to the bit, since each does the same arithmetic in the same order (the closed
loop's runs must not change)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agent.control import clearance_kernels
from agent.control.clearance import (
    BAND,
    BLOCKED,
    CLEAR,
    Motions,
    free_travel_reference,
    intruders_ok_reference,
    max_scale,
    max_scale_reference,
)
from agent.control.geometry import motion_poses, rectangle_segment_distance, unit_motion
from agent.control.give_way import Walkers
from agent.control.local_planner import ArcPlanner, Plan, choose_reference
from agent.control.navigation import NavigationField
from agent.control.obstacles import Capsules
from agent.control.settings import ControllerSettings
from agent.kinematics.vehicle import VehicleSpec
from agent.task import Task
from tests.unit.control.harness import Harness
from tests.unit.control.test_clearance import local_state, random_capsules
from tests.unit.control.test_closed_loop import u_scene
from tests.unit.control.test_navigation import field_with_u

SPEC = VehicleSpec()
SETTINGS = ControllerSettings()


def random_state(rng: np.random.Generator, n: int = 80) -> np.ndarray:
    """A state (n, n) about the vehicle at the origin (cell (40, 40), 5 cm): clear and band
    with blocked blobs, the vehicle's own cells clear."""
    state = np.where(rng.random((n, n)) < 0.85, CLEAR, BAND).astype(np.uint8)
    for _ in range(6):
        cy, cx = rng.integers(0, n, 2)
        state[max(cy - 2, 0) : cy + 2, max(cx - 2, 0) : cx + 2] = BLOCKED
    state[30:50, 30:50] = CLEAR
    return state


def test_the_compiled_rectangle_distance_equals_the_numpy_one(rng: np.random.Generator) -> None:
    caps = random_capsules(rng, 2000, spread=1.5)
    a, b = caps.a.copy(), caps.b.copy()
    b[:50] = a[:50]  # points
    got = clearance_kernels.rectangle_segment_distances(a, b, 0.4, 0.3)
    np.testing.assert_array_equal(got, rectangle_segment_distance(a, b, 0.4, 0.3))
    assert (got == 0.0).sum() > 50 and (got > 0.0).sum() > 50


@pytest.mark.parametrize("seed", range(6))
def test_the_swept_check_with_intruders_equals_its_numpy_reference(seed: int) -> None:
    """Intruders about the outline, some reaching it: the free travel of random motions
    equals the reference's (grid and intruders, every step of every motion)."""
    rng = np.random.default_rng(seed)
    caps = random_capsules(rng, 5, spread=0.6)
    local = local_state(random_state(rng), caps)
    v = np.concatenate([rng.uniform(-0.5, 0.5, 60), [0.0, 0.0, 0.5, -0.2]])
    w = np.concatenate([rng.uniform(-1.5, 1.5, 60), [1.0, -1.0, 0.0, 0.0]])
    pose = np.array([*rng.uniform(-0.1, 0.1, 2), rng.uniform(-math.pi, math.pi)])
    got = local.free_travel(pose, v, w)
    motions = Motions.of(v, w, SPEC, SETTINGS)
    np.testing.assert_array_equal(got, free_travel_reference(local, pose, motions))
    grid_only = free_travel_reference(local_state(local.state), pose, motions)
    assert (got < grid_only).any() and (got == grid_only).any()  # the intruders limit some


def test_the_first_step_an_intruder_stops_equals_its_numpy_reference(
    rng: np.random.Generator,
) -> None:
    """Without the grid's limit (every motion searched to its end): the first step at which
    the outline comes nearer an intruder, per motion."""
    n = round(SETTINGS.sweep_reach_m / SETTINGS.sweep_step_m) + 1
    steps = np.arange(n) * SETTINGS.sweep_step_m
    hx, hy = 0.5 * SPEC.length_m, 0.5 * SPEC.width_m
    limited = 0
    for _ in range(20):
        caps = random_capsules(rng, int(rng.integers(1, 8)), spread=0.8)
        local = local_state(np.full((80, 80), CLEAR, dtype=np.uint8), caps)
        v_unit, w_unit = unit_motion(rng.uniform(-0.5, 0.5, 40), rng.uniform(-1.5, 1.5, 40),
                                     SPEC.circumradius_m)  # fmt: skip
        pose = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(-math.pi, math.pi)])
        ok = intruders_ok_reference(local, pose, motion_poses(v_unit, w_unit, steps))
        ok[:, 0] = True
        want = np.where((~ok).any(axis=1), (~ok).argmax(axis=1), n)
        got = clearance_kernels.first_closer(
            v_unit, w_unit, np.full(v_unit.size, n), SETTINGS.sweep_step_m, caps.a, caps.b,
            caps.reach, *pose.tolist(), hx, hy,
        )  # fmt: skip
        np.testing.assert_array_equal(got, want)
        limited += int((got < n).sum())
    assert limited > 50


def test_the_compiled_braking_scale_equals_its_numpy_reference(rng: np.random.Generator) -> None:
    v = np.concatenate([rng.uniform(-0.5, 0.5, 300), [0.0, 0.0, 0.3]])
    w = np.concatenate([rng.uniform(-1.5, 1.5, 300), [0.0, 1.0, 0.0]])
    d_free = np.concatenate([rng.uniform(0.0, 1.2, 300), [0.5, 0.0, 0.01]])
    for tau, margin in ((0.1, 0.025), (0.3, 0.0)):
        got = max_scale(v, w, d_free, SPEC, tau, margin)
        np.testing.assert_array_equal(got, max_scale_reference(v, w, d_free, SPEC, tau, margin))
        assert ((got > 0.0) & (got < 1.0)).sum() > 50 and (got == 1.0).any()


def test_the_compiled_path_equals_the_cell_by_cell_walk(rng: np.random.Generator) -> None:
    field = field_with_u()
    lo = field.origin_xy - 0.3
    hi = field.origin_xy + np.array(field.shape[::-1]) * field.cell_m + 0.3
    for _ in range(300):
        xy = rng.uniform(lo, hi)
        length, spacing = float(rng.uniform(0.0, 4.0)), float(rng.uniform(0.01, 0.8))
        got = field.path(xy, length, spacing)
        want = field.path_reference(xy, length, spacing)
        assert got.shape == want.shape
        np.testing.assert_array_equal(got, want)


def test_covers_is_the_grid_less_its_border(rng: np.random.Generator) -> None:
    field = field_with_u()
    lo = field.origin_xy
    hi = field.origin_xy + np.array(field.shape[::-1]) * field.cell_m
    for _ in range(500):
        xy = rng.uniform(lo - 1.0, hi + 1.0)
        border = float(rng.uniform(0.0, 1.0))
        want = bool((xy >= lo + border).all() and (xy <= hi - border).all())
        assert field.covers(xy, border) == want
    assert not NavigationField(SPEC, SETTINGS).covers(np.zeros(2), 0.0)


def assert_same_plan(got: Plan, want: Plan) -> None:
    assert got.speed_m_s == want.speed_m_s and got.yaw_rate_rad_s == want.yaw_rate_rad_s
    assert got.reason == want.reason
    np.testing.assert_array_equal(got.rollout_xy, want.rollout_xy)


def test_the_compiled_arc_planner_equals_its_numpy_reference(rng: np.random.Generator) -> None:
    """Random poses in and about the U, random clear space and intruders, with and without a
    speed cap and the unstick rule: the same plan to the bit."""
    field = field_with_u()
    planner = ArcPlanner(SPEC, SETTINGS)
    reasons = set()
    for i in range(200):
        caps = random_capsules(rng, int(rng.integers(0, 4)), spread=0.6)
        state = random_state(rng)
        if i % 5 == 0:
            state[:] = BLOCKED
            state[30:50, 30:50] = CLEAR
        pose = np.array([*rng.uniform([-1.0, -1.5], [3.5, 1.5]), rng.uniform(-math.pi, math.pi)])
        local = local_state(state, caps)
        shifted = type(local)(
            origin_xy=pose[:2] - 2.0, cell_m=local.cell_m, state=local.state,
            intruders=Capsules(caps.a + pose[:2], caps.b + pose[:2], caps.radius,
                               caps.inflation, caps.moving, caps.obstacle_id),
            mover_intrudes=False, spec=SPEC, settings=SETTINGS,
        )  # fmt: skip
        tau = float(rng.uniform(0.1, 0.3))
        cap = None if i % 3 else float(rng.uniform(0.0, 0.4))
        unstick = i % 4 == 1
        # Walkers about the vehicle (their own draws: the other inputs stay as they were).
        w_rng = np.random.default_rng(i)
        k = int(w_rng.integers(0, 3)) if i % 2 else 0
        walkers = Walkers(
            pose[:2] + w_rng.uniform(-2.0, 2.0, (k, 2)), w_rng.uniform(-0.8, 0.8, (k, 2)),
            w_rng.uniform(0.15, 0.3, k),
            np.where(w_rng.random(k) < 0.5, 0.0, w_rng.uniform(0.0, 5.0, k)), 0.0,
        )  # fmt: skip
        got = planner.choose(pose, shifted, field, tau, cap, unstick, walkers)
        want = choose_reference(planner, pose, shifted, field, tau, cap, unstick, walkers)
        assert_same_plan(got, want)
        reasons.add(got.reason)
    assert reasons == {"", "unknown_ahead", "blocked"}


def test_in_the_closed_loop_every_plan_equals_the_reference(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Out of the U (escaping, turning on the spot, tight spots): each command's plan."""
    plans = 0
    choose = ArcPlanner.choose

    def checked(self: ArcPlanner, *args: object, **kwargs: object) -> Plan:
        nonlocal plans
        got = choose(self, *args, **kwargs)  # type: ignore[arg-type]
        assert_same_plan(got, choose_reference(self, *args, **kwargs))  # type: ignore[arg-type]
        plans += 1
        return got

    monkeypatch.setattr(ArcPlanner, "choose", checked)
    Harness(u_scene(), Task("goto", (3.5, 0.0))).run(20.0)
    assert plans > 100
