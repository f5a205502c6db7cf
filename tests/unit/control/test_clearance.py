"""Known clear space: the profile's cells, the local state's rules, the swept check, and the
compiled kernels against their numpy references."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agent.control import clearance_kernels, navigation_kernels
from agent.control.clearance import (
    BAND,
    BLOCKED,
    CLEAR,
    UNSEEN,
    ClearanceMap,
    LocalState,
    Motions,
    capsule_cells_reference,
    compose_cells_reference,
    free_travel_reference,
    look_ahead_row,
    profile_box_reference,
    rasterise_profile,
    record_profile,
    sector_minimum,
)
from agent.control.geometry import outline_perimeter, rectangle_segment_distance
from agent.control.memory_clock import DriftClock, MovingClock
from agent.control.navigation import core_points
from agent.control.obstacles import Capsules, capsules_from_view
from agent.control.settings import ControllerSettings
from agent.kinematics.vehicle import VehicleSpec
from agent.task import Task
from tests.unit.control.harness import Harness, Scene
from tests.unit.control.test_safety import view

SPEC = VehicleSpec()
SETTINGS = ControllerSettings()


def random_capsules(rng: np.random.Generator, k: int, spread: float = 2.0) -> Capsules:
    a = rng.uniform(-spread, spread, (k, 2))
    b = a + rng.uniform(-0.8, 0.8, (k, 2)) * (rng.random((k, 1)) < 0.6)
    return Capsules(
        a=a, b=b, radius=rng.uniform(0.0, 0.3, k) * (rng.random(k) < 0.4),
        inflation=rng.uniform(0.03, 0.2, k), moving=rng.random(k) < 0.2,
        obstacle_id=np.arange(k, dtype=np.int64),
    )  # fmt: skip


def test_sector_minimum_matches_a_brute_force_circular_window(rng: np.random.Generator) -> None:
    ranges = rng.uniform(0.0, 2.5, 360)
    lo = rng.integers(-400, 400, 500)
    length = rng.integers(1, 200, 500)
    got = sector_minimum(ranges, lo, lo + length - 1)
    want = [ranges[np.arange(a, a + n) % 360].min() for a, n in zip(lo, length, strict=True)]
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_profile_record_equals_its_numpy_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    yaw = rng.uniform(-math.pi, math.pi)
    ahead = np.array([math.cos(yaw), math.sin(yaw)])
    scene = Scene(cylinders=[(*(ahead * rng.uniform(0.9, 1.3)).tolist(), 0.15)])
    for _ in range(6):
        scene.cylinders.append((*rng.uniform(-2.5, 2.5, 2).tolist(), 0.2))
    h = Harness(scene, Task("goto", (5.0, 0.0)))
    h.pose = np.array([0.0, 0.0, yaw])
    v = h.vector(0.7)
    for cell in (0.05, 0.1):
        origin = np.array([-4.0, -4.0]) + rng.uniform(0, cell, 2)
        n = int(8.0 / cell)
        ref = rasterise_profile(v, h.pose, origin, cell, (n, n), 0.3, SETTINGS)
        assert ref is not None
        rows, cols, clear, suspect = ref
        clear_s = np.full((n, n), -np.inf)
        suspect_s = np.full((n, n), -np.inf)
        record_profile(v, h.pose, origin, cell, clear_s, suspect_s, 0.3, SETTINGS)
        np.testing.assert_array_equal(clear_s[rows, cols] == 0.7, clear)
        np.testing.assert_array_equal(suspect_s[rows, cols] == 0.7, suspect)
        assert clear.sum() > 20 and suspect.sum() > 0
        outside = np.ones((n, n), dtype=bool)
        outside[rows, cols] = False
        assert np.isinf(clear_s[outside]).all()


def test_only_sector_ends_at_hits_mark_possible_surfaces() -> None:
    """With ``free_end_hit`` given, a sector ending where the agent's knowledge ends marks
    no possible surface (it did, and shut the way with surfaces that were not there); one
    ending at a hit does, as every end did before (and does for an older agent)."""
    rng = np.random.default_rng(7)
    scene = Scene(cylinders=[(1.1, 0.0, 0.15), (0.2, 1.2, 0.2), (-1.0, -0.9, 0.2)])
    h = Harness(scene, Task("goto", (5.0, 0.0)))
    v = h.vector(0.7)
    origin, n, cell = np.array([-4.0, -4.0]), 160, 0.05
    marks = {}
    for name, ends in (
        ("older agent", np.zeros(0, np.uint8)),
        ("all hits", np.ones(360, np.uint8)),
        ("none", np.zeros(360, np.uint8)),
        ("some", (rng.random(360) < 0.5).astype(np.uint8)),
    ):
        w = dataclasses.replace(v, free_end_hit=ends)
        ref = rasterise_profile(w, h.pose, origin, cell, (n, n), 0.3, SETTINGS)
        assert ref is not None
        rows, cols, clear, suspect = ref
        clear_s, suspect_s = np.full((n, n), -np.inf), np.full((n, n), -np.inf)
        record_profile(w, h.pose, origin, cell, clear_s, suspect_s, 0.3, SETTINGS)
        np.testing.assert_array_equal(suspect_s[rows, cols] == 0.7, suspect)
        np.testing.assert_array_equal(clear_s[rows, cols] == 0.7, clear)
        marks[name] = suspect_s == 0.7
    assert marks["older agent"].sum() > 0
    np.testing.assert_array_equal(marks["all hits"], marks["older agent"])
    assert not marks["none"].any()
    assert 0 < marks["some"].sum() < marks["all hits"].sum()


def test_the_compiled_record_of_both_profiles_equals_its_numpy_reference() -> None:
    """A view with a far profile (clear from 0.55 m to 1.2 m where the profile is 0): the
    compiled record is the reference's two passes together, and the far pass marks no
    possible surface."""
    v = view(1.0, free_m=0.0)
    far = np.where(np.abs(v.free_bearing_rad) <= math.radians(20.0) + 1e-9, 1.2, 0.0)
    v = dataclasses.replace(v, free_far_m=far, free_far_from_m=0.55)
    origin, n, pose = np.array([-4.0, -4.0]), 160, np.zeros(3)
    clear_s = np.full((n, n), -np.inf)
    suspect_s = np.full((n, n), -np.inf)
    record_profile(v, pose, origin, 0.05, clear_s, suspect_s, 0.3, SETTINGS)
    want_clear = np.zeros((n, n), dtype=bool)
    want_suspect = np.zeros((n, n), dtype=bool)
    for from_near in (False, True):
        ref = rasterise_profile(v, pose, origin, 0.05, (n, n), 0.3, SETTINGS, from_near)
        if ref is not None:
            rows, cols, clear, suspect = ref
            want_clear[rows, cols] |= clear
            want_suspect[rows, cols] |= suspect
    far_pass = rasterise_profile(v, pose, origin, 0.05, (n, n), 0.3, SETTINGS, True)
    assert far_pass is not None and far_pass[2].sum() > 20 and not far_pass[3].any()
    np.testing.assert_array_equal(np.isfinite(clear_s), want_clear)
    np.testing.assert_array_equal(np.isfinite(suspect_s), want_suspect)


def test_a_cell_is_clear_only_if_all_of_it_lies_within_the_profile() -> None:
    """The profile clear to 1.0 m over ±20°: no cell reaching beyond 1.0 m from the centre of
    scanning, or outside the lit sectors by its centre, is clear; cells well inside are."""
    v = view(1.0, free_m=1.0)
    origin = np.array([-4.0, -4.0])
    rows, cols, clear, suspect = rasterise_profile(  # type: ignore[misc]
        v, np.zeros(3), origin, 0.05, (160, 160), 0.3, SETTINGS
    )
    ys, xs = np.nonzero(clear)
    cx = origin[0] + (cols.start + xs + 0.5) * 0.05 - 0.3
    cy = origin[1] + (rows.start + ys + 0.5) * 0.05
    rng_ = np.hypot(cx, cy)
    assert (rng_ + 0.05 * math.sqrt(0.5) <= 1.0 + 1e-12).all()
    assert (np.abs(np.degrees(np.arctan2(cy, cx))) <= 20.5).all()
    assert clear[
        int((0.0 - origin[1]) / 0.05) - rows.start, int((1.0 - origin[0]) / 0.05) - cols.start
    ]
    # The sector ends at 1.0 m, nearer than suspect_max_range_m: a possible surface there.
    ys, xs = np.nonzero(suspect)
    cx = origin[0] + (cols.start + xs + 0.5) * 0.05 - 0.3
    cy = origin[1] + (rows.start + ys + 0.5) * 0.05
    assert (np.abs(np.hypot(cx, cy) - 1.075) <= 0.075 + 0.05).all()


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_local_state_equals_its_numpy_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 60

    def times(p: float) -> np.ndarray:
        return np.where(rng.random((n, n)) < p, rng.uniform(0.0, 10.0, (n, n)), -np.inf)

    grids = (times(0.6), times(0.2), times(0.2), times(0.3))
    origin = np.array([-1.5, -1.5])
    pose = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(-math.pi, math.pi)])
    lo, size = (3, 5), (50, 52)
    ref_state, ref_open = compose_cells_reference(
        grids, lo, size, origin, 0.05, pose, SPEC, SETTINGS, 10.0
    )
    state, open_cells = clearance_kernels.compose_cells(
        *grids, lo[0], lo[1], size[0], size[1], -1.5, -1.5, 0.05,
        *pose.tolist(), 0.3, 0.4, 0.3, math.tan(SETTINGS.window_half_rad), 0.4, 2.5,
        10.0 - SETTINGS.clear_memory_s, 10.0 - SETTINGS.suspect_memory_s,
        10.0 - SETTINGS.footprint_memory_s,
    )  # fmt: skip
    np.testing.assert_array_equal(state, ref_state)
    np.testing.assert_array_equal(open_cells, ref_open)
    assert {int(v) for v in np.unique(state)} == {int(BLOCKED), int(CLEAR), int(BAND), int(UNSEEN)}


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_capsule_marks_equal_their_numpy_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    caps = random_capsules(rng, 30)
    n, cell = 80, 0.05
    origin = np.array([-2.0, -2.0])
    open_cells = rng.random((n, n)) < 0.8
    hit = np.zeros((n, n), dtype=bool)
    clearance_kernels.mark_capsules(hit, open_cells, -2.0, -2.0, cell, caps.a, caps.b, caps.reach)
    ys, xs = np.mgrid[0:n, 0:n]
    centres = np.stack([origin[0] + (xs + 0.5) * cell, origin[1] + (ys + 0.5) * cell], -1)
    ref = capsule_cells_reference(centres.reshape(-1, 2), caps, cell * math.sqrt(0.5))
    np.testing.assert_array_equal(hit, ref.reshape(n, n) & open_cells)


def test_the_compiled_outline_gaps_equal_the_rectangle_distance(rng: np.random.Generator) -> None:
    caps = random_capsules(rng, 400, spread=1.5)
    pose = np.array([0.2, -0.1, 0.7])
    got = clearance_kernels.outline_gaps(caps.a, caps.b, *pose.tolist(), 0.4, 0.3)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    R = np.array([[c, s], [-s, c]])
    want = rectangle_segment_distance(
        (caps.a - pose[:2]) @ R.T, (caps.b - pose[:2]) @ R.T, 0.4, 0.3
    )
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert (got == 0.0).sum() > 10 and (got > 0.0).sum() > 10


def test_rectangle_segment_distance_matches_dense_sampling(rng: np.random.Generator) -> None:
    caps = random_capsules(rng, 300, spread=1.2)
    got = rectangle_segment_distance(caps.a, caps.b, 0.4, 0.3)
    f = np.linspace(0.0, 1.0, 2001)[None, :, None]
    pts = caps.a[:, None] + f * (caps.b - caps.a)[:, None]
    inside = (np.abs(pts[..., 0]) <= 0.4) & (np.abs(pts[..., 1]) <= 0.3)
    outside_d = np.hypot(
        np.maximum(np.abs(pts[..., 0]) - 0.4, 0), np.maximum(np.abs(pts[..., 1]) - 0.3, 0)
    )
    want = np.where(inside.any(axis=1), 0.0, outside_d.min(axis=1))
    np.testing.assert_allclose(got, want, atol=2e-3)  # sampling 1/2000 of ≤ 2.3 m


def test_the_compiled_core_marks_equal_their_numpy_reference(rng: np.random.Generator) -> None:
    caps = random_capsules(rng, 40, spread=3.0)
    n, cell = 70, 0.1
    grid = np.full((n, n), -np.inf)
    navigation_kernels.mark_cores(grid, 1.0, -3.5, -3.5, cell, caps.a, caps.b, caps.radius)
    pts = core_points(caps, 0.5 * cell)
    ix = np.floor((pts[:, 0] + 3.5) / cell).astype(int)
    iy = np.floor((pts[:, 1] + 3.5) / cell).astype(int)
    ok = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n)
    want = np.full((n, n), -np.inf)
    want[iy[ok], ix[ok]] = 1.0
    np.testing.assert_array_equal(grid, want)


def local_state(state: np.ndarray, intruders: Capsules | None = None) -> LocalState:
    empty = Capsules(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0),
                     np.zeros(0, dtype=bool), np.zeros(0, dtype=np.int64))  # fmt: skip
    return LocalState(
        origin_xy=np.array([-2.0, -2.0]), cell_m=0.05, state=state.astype(np.uint8),
        intruders=intruders if intruders is not None else empty, mover_intrudes=False,
        spec=SPEC, settings=SETTINGS,
    )  # fmt: skip


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_swept_check_equals_its_numpy_reference(seed: int) -> None:
    """On random states with blocked blobs; the reference moves every perimeter point, the
    kernel only the leading ones: the same free travel."""
    rng = np.random.default_rng(seed)
    n = 80
    state = np.where(rng.random((n, n)) < 0.7, CLEAR, BAND).astype(np.uint8)
    for _ in range(12):
        cy, cx = rng.integers(0, n, 2)
        state[max(cy - 2, 0) : cy + 2, max(cx - 2, 0) : cx + 2] = BLOCKED
    state[30:50, 30:50] = CLEAR  # the vehicle's own cells
    local = local_state(state)
    v = np.concatenate([rng.uniform(-0.5, 0.5, 60), [0.0, 0.0, 0.5]])
    w = np.concatenate([rng.uniform(-1.5, 1.5, 60), [1.0, -1.0, 0.0]])
    pose = np.array([0.0, 0.0, rng.uniform(-math.pi, math.pi)])
    got = local.free_travel(pose, v, w)
    want = free_travel_reference(local, pose, Motions.of(v, w, SPEC, SETTINGS))
    np.testing.assert_array_equal(got, want)
    assert len(np.unique(got)) > 5


@pytest.mark.parametrize("seed", range(3))
def test_the_compiled_look_ahead_equals_its_numpy_reference(seed: int) -> None:
    """As above, with unknown cells in and beside the window (``UNSEEN``, ``BAND``) and the
    look-ahead row: the same free travel, and no longer than without the row."""
    rng = np.random.default_rng(10 + seed)
    n = 80
    state = np.where(rng.random((n, n)) < 0.85, CLEAR, BAND).astype(np.uint8)
    for _ in range(10):
        cy, cx = rng.integers(0, n, 2)
        state[max(cy - 2, 0) : cy + 2, max(cx - 2, 0) : cx + 2] = rng.choice([BLOCKED, UNSEEN])
    state[30:50, 30:50] = CLEAR
    plain = local_state(state)
    local = dataclasses.replace(plain, look_ahead_row=look_ahead_row(SPEC, SETTINGS))
    v = np.concatenate([rng.uniform(-0.5, 0.5, 60), [0.0, 0.5, -0.5]])
    w = np.concatenate([rng.uniform(-1.5, 1.5, 60), [1.0, 0.0, 0.0]])
    pose = np.array([0.0, 0.0, rng.uniform(-math.pi, math.pi)])
    got = local.free_travel(pose, v, w)
    want = free_travel_reference(local, pose, Motions.of(v, w, SPEC, SETTINGS))
    np.testing.assert_array_equal(got, want)
    without = plain.free_travel(pose, v, w)
    assert (got <= without).all() and (got < without).any()
    np.testing.assert_array_equal(got[v <= 0.0], without[v <= 0.0])  # forward only


def test_a_forward_motion_stops_before_unknown_space_reaches_the_near_limit() -> None:
    """Known clear to 0.5 m ahead of the bumper (x = 0.9 m), unknown (in the window) beyond:
    without the row the bumper may go up to it, with it only until the row (0.3 m ahead of
    the bumper) reaches it; a wall there (``BLOCKED``) is the perimeter's to stop at."""
    for far, want_plain, want_row in ((UNSEEN, 0.5, 0.2), (BAND, 0.5, 0.2), (BLOCKED, 0.5, 0.5)):
        state = np.full((80, 80), CLEAR, dtype=np.uint8)
        state[:, round((0.9 + 2.0) / 0.05) :] = far
        plain = local_state(state)
        local = dataclasses.replace(plain, look_ahead_row=look_ahead_row(SPEC, SETTINGS))
        ahead = np.array([0.4]), np.array([0.0])
        assert plain.free_travel(np.zeros(3), *ahead)[0] == pytest.approx(want_plain, abs=0.051)
        assert local.free_travel(np.zeros(3), *ahead)[0] == pytest.approx(want_row, abs=0.051)


def test_an_intruding_obstacle_lets_the_vehicle_back_off_but_not_close_in() -> None:
    """A wall 2 cm in front of the bumper (inside its 3σ inflation): forward is refused,
    reversing and turning away are free."""
    state = np.full((80, 80), CLEAR, dtype=np.uint8)
    wall = Capsules(
        np.array([[0.42, -1.0]]), np.array([[0.42, 1.0]]), np.zeros(1), np.array([0.06]),
        np.zeros(1, dtype=bool), np.zeros(1, dtype=np.int64),
    )  # fmt: skip
    local = local_state(state, wall)
    d = local.free_travel(np.zeros(3), np.array([0.3, -0.3, 0.0]), np.array([0.0, 0.0, 1.0]))
    assert d[0] == 0.0
    assert d[1] == pytest.approx(SETTINGS.sweep_reach_m)
    assert d[2] == 0.0  # turning on the spot swings the front corners into it


def test_in_the_window_memory_counts_until_a_possible_surface_is_seen() -> None:
    """Driven up from 1.5 m back (the flanks ahead were in the window then), then a profile
    with nothing lit: what was seen clear before still counts (static things do not
    appear; a mover that does is seen and marks its place); a profile that ends 0.6 m
    ahead marks a possible surface there, and the way ahead stops short of it."""
    cm = ClearanceMap(SPEC, SETTINGS)
    caps = capsules_from_view(view(0.0), SETTINGS)
    for i in range(16):
        cm.add_profile(view(0.1 * i, free_m=2.5), np.array([-1.5 + 0.1 * i, 0.0, 0.0]), caps)
    straight = np.array([0.5]), np.array([0.0])
    local = cm.compose(1.5, np.zeros(3), caps)
    assert local.free_travel(np.zeros(3), *straight)[0] == SETTINGS.sweep_reach_m
    cm.add_profile(view(1.6, free_m=0.0), np.zeros(3), caps)
    d = cm.compose(1.6, np.zeros(3), caps).free_travel(np.zeros(3), *straight)[0]
    assert d == SETTINGS.sweep_reach_m
    cm.add_profile(view(1.7, free_m=0.6), np.zeros(3), caps)
    d = cm.compose(1.7, np.zeros(3), caps).free_travel(np.zeros(3), *straight)[0]
    bumper_to_head = 0.5 * SPEC.length_m - SPEC.head_offset_m
    assert 0.3 < d <= 0.6 - bumper_to_head


@pytest.mark.parametrize("scanned", [True, False])
def test_silence_counts_to_silent_range_only_while_the_window_is_scanned(scanned: bool) -> None:
    """The start's disc (0.92 m about the centre) known, then a profile with nothing lit:
    while the head scans the forward window, its silence is clear space out to
    ``silent_range_m`` from the centre of scanning; once it looked elsewhere, nothing
    beyond the disc."""
    cm = ClearanceMap(SPEC, SETTINGS)
    caps = capsules_from_view(view(0.0), SETTINGS)
    cm.add_disc(0.0, np.zeros(2), 0.92)
    cm.window_scanned = scanned
    cm.add_profile(view(0.1, free_m=0.0), np.zeros(3), caps)
    local = cm.compose(0.1, np.zeros(3), caps)

    def state(x: float) -> int:  # the cell straight ahead at x from the centre
        i = int((x - local.origin_xy[0]) / local.cell_m)
        j = int((0.0 - local.origin_xy[1]) / local.cell_m)
        return int(local.state[j, i])

    assert state(0.8) == CLEAR  # the disc
    beyond = SPEC.head_offset_m + SETTINGS.silent_range_m
    assert (state(beyond - 0.1) == CLEAR) == scanned  # silent, or unknown
    assert state(beyond + 0.1) != CLEAR


def _silent_at(cm: ClearanceMap, pose: np.ndarray, bearing_deg: float, r: float) -> bool:
    """Whether the cell at ``r`` from the centre of scanning, ``bearing_deg`` from the
    heading (``base_link``), was recorded silent."""
    assert cm.origin_xy is not None
    x, y, yaw = pose
    hx, hy = x + SPEC.head_offset_m * math.cos(yaw), y + SPEC.head_offset_m * math.sin(yaw)
    a = yaw + math.radians(bearing_deg)
    ix = math.floor((hx + r * math.cos(a) - cm.origin_xy[0]) / cm.cell_m)
    iy = math.floor((hy + r * math.sin(a) - cm.origin_xy[1]) / cm.cell_m)
    return bool(np.isfinite(cm.last_silent[iy, ix]))


@pytest.mark.parametrize("scanned", [True, False])
def test_silence_is_read_in_the_window_the_vector_names(scanned: bool) -> None:
    """The head panned 60° left, its scan (40°, 80°) named by the vector, nothing lit but a
    sector at 60° clear to 0.6 m: silence about 60° (the sectors read by the vehicle's
    bearings, whatever its heading), none beyond the lit sector's end, none ahead, and none
    outside the window; whatever the forward window's inference says."""
    pose = np.array([0.2, -0.1, 0.5])
    v = view(0.1, free_m=0.0)
    lit = np.abs(v.free_bearing_rad - math.radians(60.0)) <= math.radians(2.0) + 1e-9
    v = dataclasses.replace(
        v, free_range_m=np.where(lit, 0.6, 0.0),
        scan_window_rad=np.radians([40.0, 80.0]),
    )  # fmt: skip
    cm = ClearanceMap(SPEC, SETTINGS)
    cm.window_scanned = scanned
    cm.add_disc(0.0, pose[:2], 0.92)  # the way nearer than the near limit: known clear
    cm.add_profile(v, pose, capsules_from_view(v, SETTINGS))
    for r in (0.5, 0.7, 0.9):
        assert _silent_at(cm, pose, 45.0, r), r  # silent: in the window, unlit
        assert _silent_at(cm, pose, 75.0, r), r
        assert not _silent_at(cm, pose, 0.0, r), r  # ahead: not scanned
        assert not _silent_at(cm, pose, 90.0, r), r  # beside the window
        assert not _silent_at(cm, pose, 30.0, r), r
    assert _silent_at(cm, pose, 60.0, 0.45)  # short of the lit sector's end
    assert not _silent_at(cm, pose, 60.0, 0.8)  # lit to 0.6 m only: a surface may be there
    assert not _silent_at(cm, pose, 45.0, SETTINGS.silent_range_m + 0.1)
    # Within the window's sectors only: their edges at 40.5° and 79.5°.
    silent = np.argwhere(np.isfinite(cm.last_silent))
    assert cm.origin_xy is not None
    centres = cm.origin_xy + (silent[:, ::-1] + 0.5) * cm.cell_m
    head = pose[:2] + SPEC.head_offset_m * np.array([math.cos(pose[2]), math.sin(pose[2])])
    d = centres - head
    bearing = np.degrees(np.arctan2(d[:, 1], d[:, 0]) - pose[2])
    assert len(bearing) > 50
    assert bearing.min() >= 40.5 - 1e-9 and bearing.max() <= 79.5 + 1e-9


def test_no_silence_where_the_scan_returned_light_though_the_profile_is_0() -> None:
    """The head panned 60° left, its scan (40°, 80°) named, the profile 0 throughout; the
    vector says the scan returned light at 0.7 m in the sectors about 60° (a valid reading
    at the window's edge whose clear sliver the agent aged away, a mixed sample): silence
    stops short of it there, and reaches the silent range elsewhere in the window; a
    sector dark to 0 (light at no known range) is silent nowhere."""
    pose = np.array([0.2, -0.1, 0.5])
    v = view(0.1, free_m=0.0)
    b = np.degrees(v.free_bearing_rad)
    in_window = (b >= 40.0) & (b <= 80.0)
    dark = np.where(in_window, 2.5, 0.0)
    dark[np.abs(b - 60.0) <= 2.0 + 1e-9] = 0.7
    dark[np.abs(b - 72.0) <= 2.0 + 1e-9] = 0.0
    v = dataclasses.replace(v, scan_window_rad=np.radians([40.0, 80.0]), scan_dark_m=dark)
    cm = ClearanceMap(SPEC, SETTINGS)
    cm.add_disc(0.0, pose[:2], 0.92)  # the way nearer than the near limit: known clear
    cm.add_profile(v, pose, capsules_from_view(v, SETTINGS))
    assert _silent_at(cm, pose, 60.0, 0.5)  # nearer than the light: dark
    assert not _silent_at(cm, pose, 60.0, 0.8)  # past it: a surface is there
    assert not _silent_at(cm, pose, 60.0, 0.95)
    for r in (0.5, 0.8, 0.95):
        assert _silent_at(cm, pose, 47.0, r), r  # dark to the far limit
        assert not _silent_at(cm, pose, 72.0, r), r
    with pytest.raises(ValueError, match="scan_dark_m"):
        dataclasses.replace(v, scan_dark_m=np.zeros(3))


def test_the_memory_records_what_was_seen_when_set_to() -> None:
    """A vector whose aged profile is 0 ahead (everything aged away) but whose seen profile
    is clear to 1.5 m: with ``record_seen`` (the default) the memory holds the way ahead
    clear as it would from an aged profile that said 1.5 m; without it (and without seen
    profiles) it records the aged one."""
    pose = np.zeros(3)
    aged = view(0.1, free_m=0.0)
    seen = view(0.1, free_m=1.5)
    both = dataclasses.replace(
        aged, seen_range_m=seen.free_range_m, seen_far_m=seen.free_range_m,
        seen_end_hit=np.zeros(seen.free_range_m.size, dtype=np.uint8),
    )  # fmt: skip
    np.testing.assert_array_equal(both.seen.free_range_m, seen.free_range_m)
    recording = dataclasses.replace(SETTINGS, record_seen=True)
    assert SETTINGS.record_seen
    aged_only = dataclasses.replace(SETTINGS, record_seen=False)
    recorded = []
    for v, settings in ((both, recording), (seen, recording), (aged, recording),
                        (both, aged_only)):  # fmt: skip
        cm = ClearanceMap(SPEC, settings)
        cm.window_scanned = False  # no silence: the profiles alone
        cm.add_profile(v, pose)
        recorded.append(np.isfinite(cm.last_clear))
    assert recorded[0].sum() > 100
    np.testing.assert_array_equal(recorded[0], recorded[1])
    assert not recorded[2].any() and not recorded[3].any()
    with pytest.raises(ValueError, match="seen_range_m, seen_far_m and seen_end_hit"):
        dataclasses.replace(aged, seen_range_m=seen.free_range_m)


def test_the_forward_window_named_reads_as_the_forward_window_assumed() -> None:
    """The vector naming the forward window (±20°) records the same silence as the forward
    window taken as scanned (``window_half_rad``, ±19.5°); naming another stops the
    assumed one."""
    pose = np.array([0.0, 0.0, 0.3])
    v = view(0.1, free_m=0.0)
    recorded = []
    for window, scanned in (((-20.0, 20.0), False), ((), True), ((30.0, 70.0), True)):
        cm = ClearanceMap(SPEC, SETTINGS)
        cm.window_scanned = scanned
        cm.add_disc(0.0, pose[:2], 0.92)
        named = dataclasses.replace(v, scan_window_rad=np.radians(np.array(window)))
        cm.add_profile(named, pose)
        recorded.append(np.isfinite(cm.last_silent))
    assert recorded[0].sum() > 50
    np.testing.assert_array_equal(recorded[0], recorded[1])
    assert not (recorded[2] & recorded[1]).any()


@pytest.mark.parametrize(
    "window", [[0.1], [0.1, 0.2, 0.3], [0.2, 0.1], [0.2, 0.2], [-4.0, 0.1], [0.0, math.nan]]
)
def test_a_scan_window_other_than_low_high_is_refused(window: list[float]) -> None:
    with pytest.raises(ValueError, match="scan_window_rad"):
        dataclasses.replace(view(0.0), scan_window_rad=np.array(window))


def test_a_pinhole_is_filled_and_nothing_larger() -> None:
    """An unknown cell whose eight neighbours are clear counts clear; two unknown cells side
    by side, a possible surface (blocked), or an unknown cell at the edge stay as they are."""
    from agent.control.clearance import _fill_pinholes

    state = np.full((7, 9), CLEAR, dtype=np.uint8)
    state[1, 1] = BAND  # a pinhole
    state[4, 3] = state[4, 4] = BAND  # two side by side
    state[2, 6] = BLOCKED  # a possible surface
    state[0, 8] = BAND  # at the edge
    _fill_pinholes(state)
    assert state[1, 1] == CLEAR
    assert state[4, 3] == state[4, 4] == BAND
    assert state[2, 6] == BLOCKED and state[0, 8] == BAND


def test_the_local_state_rules_for_a_cell_beside_the_vehicle() -> None:
    """Beside the vehicle (outside the window): never seen, it is blind band; a possible
    surface there blocks it until ``suspect_memory_s`` has passed; seen clear since, it is
    known clear while remembered: ``clear_memory_s`` of moving, however long the vehicle
    stands still."""
    cm = ClearanceMap(SPEC, SETTINGS)
    caps = capsules_from_view(view(0.0), SETTINGS)
    cm.add_profile(view(0.0, free_m=0.0), np.zeros(3), caps)  # places the grid
    assert cm.origin_xy is not None
    iy = int((0.425 - cm.origin_xy[1]) / cm.cell_m)  # 0.1 m left of the side
    ix = int((0.025 - cm.origin_xy[0]) / cm.cell_m)

    def state_at(now: float) -> int:
        local = cm.compose(now, np.zeros(3), caps)
        jy = int((0.425 - local.origin_xy[1]) / cm.cell_m)
        jx = int((0.025 - local.origin_xy[0]) / cm.cell_m)
        return int(local.state[jy, jx])

    assert state_at(1.0) == BAND
    cm.last_suspect[iy, ix] = 1.0
    assert state_at(1.0) == BLOCKED
    assert state_at(1.0 + SETTINGS.suspect_memory_s + 0.01) == BAND
    cm.last_clear[iy, ix] = 2.0
    assert state_at(2.5) == CLEAR
    assert state_at(2.0 + SETTINGS.clear_memory_s + 0.01) == CLEAR  # standing: kept
    cm.clock.update(40.0, True)  # moving from 40 s on
    assert state_at(40.0 + SETTINGS.clear_memory_s - 0.01) == CLEAR
    assert state_at(40.0 + SETTINGS.clear_memory_s + 0.01) == BAND


def test_the_memory_clock_runs_only_while_moving() -> None:
    clock = MovingClock()
    assert clock.since(5.0, 1.0) < -1e300  # nothing yet: all of the memory holds
    clock.update(0.0, True)
    clock.update(2.0, False)  # moved 0-2 s, stood 2-10 s, moving again from 10 s
    clock.update(10.0, True)
    clock.update(9.0, False)  # older than the newest: ignored
    assert clock.reading(10.0) == 2.0 and clock.reading(11.5) == 3.5
    assert clock.since(11.5, 1.0) == pytest.approx(10.5)  # within the moving spell
    assert clock.since(11.5, 1.5) == pytest.approx(2.0)  # the whole stop is 1.5 s of moving old
    assert clock.since(11.5, 2.0) == pytest.approx(1.5)
    assert clock.since(11.5, 3.0) == pytest.approx(0.5)
    assert clock.since(11.5, 3.5) < -1e300


def test_the_drift_clock_follows_the_base_s_systematic_errors() -> None:
    clock = DriftClock(ratio_rad_per_m=0.03, track_per_rad=0.02, slip_rad2_per_m=0.0)
    assert clock.since(0.02) < -1e300  # nothing yet: all of the memory holds
    # Straight along x at 0.5 m/s from t = 0 to 2 (1 m), then standing until t = 5.
    for k in range(101):
        clock.update(0.02 * k, 0.01 * k, 0.0, 0.0)
    for k in range(150):
        clock.update(2.02 + 0.02 * k, 1.0, 0.0, 0.0)
    assert clock.sigma_since(0.0) == pytest.approx(0.03)  # 1 m driven: 0.03 rad
    assert clock.sigma_since(1.5) == pytest.approx(0.0075, abs=1e-9)
    # 0.02 rad: what was recorded before 1/3 m was driven is not trusted.
    assert clock.since(0.02) == pytest.approx(0.66, abs=0.021)
    # A turn on the spot of 1 rad one way and back: undone (signed); 3 rad one way: not.
    t = 5.0
    for yaw in [*np.linspace(0.0, 1.0, 51), *np.linspace(1.0, 0.0, 51)[1:]]:
        t += 0.02
        clock.update(t, 1.0, 0.0, float(yaw))
    assert clock.sigma_since(4.0) == pytest.approx(0.0, abs=1e-9)
    assert clock.sigma_since(5.5) == pytest.approx(0.02 * 0.48, abs=1e-3)  # from mid-turn
    for yaw in np.linspace(0.0, 3.0, 151)[1:]:
        t += 0.02
        clock.update(t, 1.0, 0.0, float(yaw))
    assert clock.sigma_since(4.0) == pytest.approx(0.06)
    assert clock.since(0.02) > 5.0 + 2.0  # only what was seen in the last turn's last third
    # Driving back along the way it came undoes the straight part too.
    back = DriftClock(0.03, 0.02, 0.0)
    for k in range(101):
        back.update(0.02 * k, 0.01 * k, 0.0, 0.0)
    for k in range(1, 101):
        back.update(2.0 + 0.02 * k, 1.0 - 0.01 * k, 0.0, 0.0)
    assert back.sigma_since(0.0) == pytest.approx(0.0, abs=1e-9)


def test_space_is_forgotten_once_the_heading_may_have_drifted() -> None:
    # A cell remembered clear from t = 2 s; then the vehicle turns on the spot one way: past
    # 1 rad (0.02 rad of heading at 2 %) the memory of it goes, long before 30 s of moving.
    cm = ClearanceMap(SPEC, dataclasses.replace(SETTINGS, memory_drift_rad=0.02))
    pose = np.array([0.0, 0.0, 0.0])
    cm.add_footprint(0.0, pose)
    assert cm.origin_xy is not None
    ix = int((1.5 - cm.origin_xy[0]) / cm.cell_m)
    iy = int((0.0 - cm.origin_xy[1]) / cm.cell_m)
    cm.last_clear[iy, ix] = 2.0
    for k in range(151):  # 1.5 rad in 3 s
        t, yaw = 2.0 + 0.02 * k, 0.01 * k
        cm.clock.update(t, True)
        cm.drift.update(t, 0.0, 0.0, yaw)
        cm.last_clear[iy, ix] = max(cm.last_clear[iy, ix], 2.0)
        if yaw == pytest.approx(0.9):
            assert cm._since(t)[0] < 2.0  # still held
    assert cm._since(5.0)[0] > 2.0  # gone
    # A base that does not drift keeps it for 30 s of moving.
    still = ClearanceMap(SPEC, dataclasses.replace(SETTINGS, drift_track_per_rad=0.0))
    for k in range(151):
        still.drift.update(2.0 + 0.02 * k, 0.0, 0.0, 0.01 * k)
    assert still.drift.since(0.02) < -1e300


def test_outline_perimeter_is_dense_enough_for_the_cells() -> None:
    pts = outline_perimeter(SPEC, SETTINGS.outline_spacing_m)
    gaps = np.hypot(*np.diff(np.vstack([pts, pts[:1]]), axis=0).T)
    assert gaps.max() <= SETTINGS.cell_m + 1e-12


@pytest.mark.parametrize("seed", range(4))
def test_the_compiled_fan_box_equals_its_numpy_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    bearings = np.radians(np.arange(-180, 180, dtype=np.float64))
    ranges = np.where(rng.random(360) < 0.3, rng.uniform(0.0, 2.5, 360), 0.0)
    head = rng.uniform(-2.0, 2.0, 2)
    yaw = float(rng.uniform(-math.pi, math.pi))
    got = clearance_kernels.fan_box(ranges, bearings, yaw, math.radians(1.0), *head, 0.15)
    want = profile_box_reference(ranges, bearings, yaw, math.radians(1.0), head, 0.15)
    np.testing.assert_allclose(got, want, rtol=0.0, atol=1e-12)
    # Nothing lit: the centre alone.
    none = clearance_kernels.fan_box(np.zeros(360), bearings, yaw, 0.01, *head, 0.15)
    assert none == (head[0], head[1], head[0], head[1])


def test_no_silence_behind_a_way_nearer_than_the_near_limit_not_known_clear() -> None:
    """A surface nearer than the near limit images off the detector and returns nothing,
    hiding what is behind it: silence needs the way there known clear. Measured in the
    random worlds (evaluate --random 24, active, run 6): a box's end 0.23 m from the head,
    its long side edge-on, and the cells beyond taken as silent; the vehicle drove into it."""
    pose = np.array([0.0, 0.0, 0.0])
    v = dataclasses.replace(view(0.1, free_m=0.0), scan_window_rad=np.radians([-20.0, 20.0]))
    unknown = ClearanceMap(SPEC, SETTINGS)
    unknown.add_profile(v, pose)
    assert not np.isfinite(unknown.last_silent).any()  # nothing known ahead of the bumper
    known = ClearanceMap(SPEC, SETTINGS)
    known.add_disc(0.0, pose[:2], 0.92)
    known.add_profile(v, pose)
    assert _silent_at(known, pose, 0.0, 0.6) and _silent_at(known, pose, 15.0, 0.9)
    # A possible surface seen since, 0.3 m ahead of the head: no silence behind it, but
    # silence still beside it.
    marked = ClearanceMap(SPEC, SETTINGS)
    marked.add_disc(0.0, pose[:2], 0.92)
    assert marked.origin_xy is not None
    ix = math.floor((SPEC.head_offset_m + 0.3 - marked.origin_xy[0]) / marked.cell_m)
    iy = math.floor((0.0 - marked.origin_xy[1]) / marked.cell_m)
    marked.last_suspect[iy, ix] = 0.05
    marked.add_profile(v, pose)
    assert not _silent_at(marked, pose, 0.0, 0.6)
    assert _silent_at(marked, pose, 15.0, 0.9)


def test_the_footprint_holds_what_the_corners_swept_between_vectors() -> None:
    # Turning on the spot at 1 rad/s, a footprint each 0.1 s: every cell a corner passed
    # through on the way is known (the body was there), not only those at each vector.
    cm = ClearanceMap(SPEC, SETTINGS)
    for k in range(11):
        cm.add_footprint(0.1 * k, np.array([0.0, 0.0, 0.1 * k]))
    assert cm.origin_xy is not None
    corners = np.array([[0.4, 0.3], [0.4, -0.3], [-0.4, 0.3], [-0.4, -0.3]])
    for yaw in np.linspace(0.0, 1.0, 201):
        c, s = math.cos(yaw), math.sin(yaw)
        at = corners @ np.array([[c, s], [-s, c]])
        ix = ((at[:, 0] - cm.origin_xy[0]) / cm.cell_m).astype(int)
        iy = ((at[:, 1] - cm.origin_xy[1]) / cm.cell_m).astype(int)
        assert np.all(cm.last_there[iy, ix] > -np.inf), yaw
    # A jump (no sweep to trust) records only where the outline is.
    far = ClearanceMap(SPEC, SETTINGS)
    far.add_footprint(0.0, np.array([0.0, 0.0, 0.0]))
    far.add_footprint(0.1, np.array([1.0, 0.0, 0.0]))
    assert far.origin_xy is not None
    mid = int((0.5 - far.origin_xy[0]) / far.cell_m), int((0.0 - far.origin_xy[1]) / far.cell_m)
    assert far.last_there[mid[1], mid[0]] == -np.inf
