"""A walker's line from its trail (agent.control.walk_lines) and its use by the walkway memory."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agent.control.obstacles import capsules_from_view
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView
from agent.control.walk_lines import (
    LineFit,
    WalkRegistry,
    fit_line,
    movers_on_lines,
    turn_points,
)
from agent.control.walkways import WalkwayMemory
from agent.kinematics.vehicle import VehicleSpec
from tests.unit.control.test_obstacle_kernels import walker_view

SETTINGS = ControllerSettings()
SPEC = VehicleSpec()


def _trail(angle_rad: float, n: int, step_m: float, noise_m: float, seed: int) -> np.ndarray:
    """``n`` places ``step_m`` apart along a line at ``angle_rad`` through (1, 2), each off
    it by Gaussian noise of ``noise_m`` both ways."""
    rng = np.random.default_rng(seed)
    u = np.array([math.cos(angle_rad), math.sin(angle_rad)])
    s = np.arange(n) * step_m
    return np.array([1.0, 2.0]) + s[:, None] * u + rng.normal(0.0, noise_m, (n, 2))


def test_the_line_is_found_within_its_sigma_over_many_trails() -> None:
    # 400 trails of 10 places 5 cm apart (a walker at 0.5 m/s, 10 vectors a second), 2 cm
    # of noise: independent places, so the fit's σ (twice the independent-sample formula's,
    # for the tracker's correlated ones) is conservative here: nearly none beyond 3σ
    # (tolerance: 1 %, where a σ that were too small by half would put ~13 % beyond it).
    beyond = 0
    for seed in range(400):
        angle = 0.7 + 0.01 * seed
        line = fit_line(_trail(angle, 10, 0.05, 0.02, seed))
        assert line is not None
        err = math.acos(min(1.0, abs(float(line.direction @ [math.cos(angle), math.sin(angle)]))))
        beyond += err > 3.0 * line.sigma_rad
    assert beyond <= 4


def test_the_sigma_falls_as_the_trail_spans_more() -> None:
    short = fit_line(_trail(0.3, 10, 0.04, 0.02, 1))
    long = fit_line(_trail(0.3, 40, 0.04, 0.02, 1))
    assert short is not None and long is not None
    assert long.sigma_rad < 0.25 * short.sigma_rad


def test_too_few_places_or_too_short_a_span_fit_no_line() -> None:
    assert fit_line(_trail(0.3, 4, 0.2, 0.0, 0)) is None  # 4 places: fewer than 5
    assert fit_line(_trail(0.3, 10, 0.02, 0.0, 0)) is None  # 0.18 m: less than 0.3 m
    assert fit_line(np.tile([1.0, 2.0], (20, 1))) is None  # standing still


def _walking(angle_rad: float, heading_rad: float) -> tuple[EnvironmentView, dict[int, LineFit]]:
    """A walker on a line at ``angle_rad`` whose vector velocity (0.5 m/s) points at
    ``heading_rad``, its velocity σ 0.5 m/s (a young track), position σ 2 cm."""
    view = dataclasses.replace(
        walker_view(0.0, [3]),
        velocity_xy=0.5 * np.array([[math.cos(heading_rad), math.sin(heading_rad)]]),
        covariance=np.diag([4e-4, 4e-4, 0.25, 0.25])[None],
    )
    line = fit_line(_trail(angle_rad, 20, 0.05, 0.0, 0))
    assert line is not None
    return view, {3: line}


def test_a_mover_is_swept_along_its_line_not_its_velocity() -> None:
    view, lines = _walking(0.0, math.radians(30.0))  # walking along x, velocity 30° off
    caps = capsules_from_view(view, SETTINGS)
    assert caps.moving[0] and caps.inflation[0] > 1.5  # the cap: where it goes is unknown
    on, velocity = movers_on_lines(
        caps, view.velocity_xy, view.covariance, lines, SETTINGS.mover_horizon_s,
        SETTINGS.covariance_sigmas, SETTINGS.mover_inflation_cap_m, SETTINGS.obstacle_margin_m,
    )  # fmt: skip
    speed = 0.5 * math.cos(math.radians(30.0))  # the velocity along the line
    np.testing.assert_allclose(velocity, [[speed, 0.0]], atol=1e-12)
    # Across the line: 3σ of the place (2 cm) and of the line's direction (the floor's
    # 2 cm over an exact trail) over the horizon's walk.
    T = SETTINGS.mover_horizon_s
    across = math.hypot(0.02, lines[3].sigma_rad * speed * T)
    assert on.inflation[0] == pytest.approx(3.0 * across + SETTINGS.obstacle_margin_m)
    assert on.inflation[0] < 0.15
    # Along it: its speed's σ (0.5 m/s) over the horizon, capped, beyond its walk.
    assert on.a[0, 1] == pytest.approx(0.0, abs=1e-9) and on.b[0, 1] == pytest.approx(0.0)
    assert on.b[0, 0] == pytest.approx(1.0 + speed * T + SETTINGS.mover_inflation_cap_m)
    assert on.a[0, 0] == pytest.approx(1.0)  # its place now: 3σ (6 cm) within the inflation
    # A walker coming the other way along the same line is swept the other way.
    view2, lines2 = _walking(0.0, math.radians(160.0))
    on2, velocity2 = movers_on_lines(
        capsules_from_view(view2, SETTINGS), view2.velocity_xy, view2.covariance, lines2,
        T, SETTINGS.covariance_sigmas, SETTINGS.mover_inflation_cap_m,
        SETTINGS.obstacle_margin_m,
    )  # fmt: skip
    assert velocity2[0, 0] < 0.0 and on2.b[0, 0] < on2.a[0, 0]


def test_a_mover_is_not_swept_past_where_its_walk_turns_back() -> None:
    # The walker at (1, 0) walking along x, its walk turning back at x = 1.4 ahead and at
    # x = 0.5 behind: its capsule runs from 0.5 to 1.4 at most, not the horizon's walk and
    # the speed's σ beyond (2.8 m out).
    view, lines = _walking(0.0, 0.0)
    caps = capsules_from_view(view, SETTINGS)
    args = (SETTINGS.mover_horizon_s, SETTINGS.covariance_sigmas,
            SETTINGS.mover_inflation_cap_m, SETTINGS.obstacle_margin_m)  # fmt: skip
    free, _ = movers_on_lines(caps, view.velocity_xy, view.covariance, lines, *args)
    assert free.b[0, 0] > 2.5
    ends = {3: np.array([[1.4, 0.0], [0.5, 0.0]])}
    held, _ = movers_on_lines(caps, view.velocity_xy, view.covariance, lines, *args, ends)
    assert held.b[0, 0] == pytest.approx(1.4) and held.a[0, 0] == pytest.approx(1.0)
    assert held.inflation[0] == pytest.approx(free.inflation[0])


def test_movers_without_a_line_and_static_obstacles_are_left_as_they_were() -> None:
    view, lines = _walking(0.0, 0.0)
    caps = capsules_from_view(view, SETTINGS)
    args = (SETTINGS.mover_horizon_s, SETTINGS.covariance_sigmas,
            SETTINGS.mover_inflation_cap_m, SETTINGS.obstacle_margin_m)  # fmt: skip
    same, velocity = movers_on_lines(caps, view.velocity_xy, view.covariance, {}, *args)
    assert same is caps
    np.testing.assert_array_equal(velocity, view.velocity_xy)
    # A static pillar (id 3, standing) with a line on record is not a mover: unchanged.
    still = dataclasses.replace(view, velocity_xy=np.zeros((1, 2)))
    caps = capsules_from_view(still, SETTINGS)
    assert not caps.moving[0]
    same, velocity = movers_on_lines(caps, still.velocity_xy, still.covariance, lines, *args)
    assert same is caps
    np.testing.assert_array_equal(velocity, np.zeros((1, 2)))


def test_a_walker_kept_on_its_walk_keeps_the_line_of_its_trail() -> None:
    # A walker walking along y = x (its places 5 cm apart), its vector velocity 40° off
    # that; once it leaves the vector it is kept on the line of its places, narrow.
    memory = WalkwayMemory(SPEC, SETTINGS)
    u = np.array([1.0, 1.0]) / math.sqrt(2.0)
    heading = math.radians(45.0 + 40.0)
    pose = np.array([-3.0, 0.0, 0.0])
    for j in range(12):
        view = dataclasses.replace(
            walker_view(10.0 + 0.1 * j, [5]),
            position_xy=(np.array([1.0, 0.0]) + 0.05 * j * u)[None],
            velocity_xy=0.5 * np.array([[math.cos(heading), math.sin(heading)]]),
            covariance=np.diag([4e-4, 4e-4, 0.25, 0.25])[None],
        )
        memory.update(view, capsules_from_view(view, SETTINGS), pose)
    assert 5 in memory.lines
    gone = walker_view(11.6, [])
    kept = memory.update(gone, capsules_from_view(gone, SETTINGS), pose)
    assert set(kept.obstacle_id) == {5}
    d = kept.b - kept.a
    np.testing.assert_allclose(np.abs(d @ u) / np.hypot(*d.T), 1.0, atol=1e-9)
    assert kept.inflation.max() < 0.3  # not the 1.5 m cap of a 40°-off velocity


def _places(track: int, t0: float, n: int, start: np.ndarray, u: np.ndarray, pace: float):
    """``n`` vectors 0.1 s apart from ``t0`` of track ``track`` walking from ``start`` along
    ``u`` at ``pace``: (times, ids, places)."""
    t = t0 + 0.1 * np.arange(n)
    return t, np.full(n, track), start + (pace * 0.1 * np.arange(n))[:, None] * u


def test_a_walker_s_new_track_joins_its_walk_and_the_walk_shows_its_pace() -> None:
    # One walker along y = 0.5·x at 0.5 m/s, tracked for 1 s (track 3), lost, and found 2 s
    # on by a new track (8) further along, its velocity 30° off its line and twice as fast
    # (as the tracks' are). A walker crossing that line (track 9) begins its own walk.
    registry = WalkRegistry()
    u = np.array([2.0, 1.0]) / math.sqrt(5.0)
    rot = np.array([[math.cos(0.52), -math.sin(0.52)], [math.sin(0.52), math.cos(0.52)]])
    times, ids, places = _places(3, 10.0, 10, np.array([0.0, 0.0]), u, 0.5)
    for t, i, p in zip(times, ids, places, strict=True):
        registry.observe(float(t), np.array([i]), p[None], (0.5 * u)[None])
    first = registry.walk_of(3)
    assert first is not None and first.line is not None
    assert first.pace == pytest.approx(0.5, abs=0.01)
    times, ids, places = _places(8, 13.0, 10, 1.5 * u, u, 0.5)
    for t, i, p in zip(times, ids, places, strict=True):
        registry.observe(float(t), np.array([i]), p[None], (1.0 * rot @ u)[None])
    assert registry.walk_of(8) is first
    assert len(first.places) == 20 and set(first.ids.tolist()) == {3, 8}
    assert abs(float(first.line.direction @ u)) == pytest.approx(1.0, abs=1e-6)
    assert first.pace == pytest.approx(0.5, abs=0.01)
    normal = np.array([-u[1], u[0]])
    registry.observe(13.5, np.array([9]), (1.0 * u)[None], (0.5 * normal)[None])
    assert registry.walk_of(9) is not first
    # Off the line by more than the gate: a walk of its own too.
    registry.observe(13.6, np.array([10]), (1.0 * u + 0.5 * normal)[None], (0.5 * u)[None])
    assert registry.walk_of(10) is not first
    assert len(registry) == 3
    # Forgotten once no track has walked it for memory_s.
    registry.observe(13.9 + registry.memory_s + 0.1, np.zeros(0, dtype=np.int64),
                     np.zeros((0, 2)), np.zeros((0, 2)))  # fmt: skip
    assert len(registry) == 0 and registry.walk_of(8) is None


def test_short_tracks_of_one_walker_join_one_walk_that_fits_its_line() -> None:
    # A walker at 0.28 m/s along a line at 19°, 2.4 m from the head, as the tracker gives
    # it: tracks of 7 vectors (0.7 s, 0.2 m: too short to fit) a new id each 1.2 s later
    # (evaluate's random run 83 of seed 0), places 1.5 cm off the line, velocities 25°
    # off. The tracks join one walk, which fits the line once it spans 0.3 m.
    rng = np.random.default_rng(7)
    registry = WalkRegistry()
    u = np.array([math.cos(math.radians(19.0)), math.sin(math.radians(19.0))])
    rot = np.array([[math.cos(0.44), -math.sin(0.44)], [math.sin(0.44), math.cos(0.44)]])
    for k in range(4):
        t0 = 10.0 + 1.9 * k
        times, ids, places = _places(20 + k, t0, 7, 0.28 * (t0 - 10.0) * u, u, 0.28)
        places = places + rng.normal(0.0, 0.015, places.shape)
        for t, i, p in zip(times, ids, places, strict=True):
            registry.observe(float(t), np.array([i]), p[None], (0.28 * rot @ u)[None])
    assert len(registry) == 1
    walk = registry.walk_of(23)
    assert walk is not None and walk.line is not None and set(walk.ids.tolist()) == {20, 21, 22, 23}
    err = math.degrees(math.acos(min(1.0, abs(float(walk.line.direction @ u)))))
    assert err < 3.0 and err < 3.0 * math.degrees(walk.line.sigma_rad)


def test_a_short_track_joins_no_walk_its_walker_could_not_have_walked_to() -> None:
    # An unfitted walk (one short track along x, last seen at 10.6 s): a new track on its
    # line but 2 m on 0.5 s later (4 m/s), one crossing it, and one while the first track
    # is still in the vector each begin a walk of their own; one 0.4 m on 1 s later joins.
    u = np.array([1.0, 0.0])

    def start() -> WalkRegistry:
        registry = WalkRegistry()
        for t, i, p in zip(*_places(1, 10.0, 7, np.zeros(2), u, 0.3), strict=True):
            registry.observe(float(t), np.array([i]), p[None], (0.3 * u)[None])
        return registry

    registry = start()
    registry.observe(11.1, np.array([2]), np.array([[2.2, 0.0]]), (0.3 * u)[None])
    assert registry.walk_of(2) is not registry.walk_of(1)
    registry = start()
    registry.observe(11.6, np.array([3]), np.array([[0.6, 0.0]]), np.array([[0.0, 0.3]]))
    assert registry.walk_of(3) is not registry.walk_of(1)
    registry = start()
    registry.observe(10.7, np.array([1, 4]), np.array([[0.21, 0.0], [0.5, 0.02]]),
                     np.array([0.3 * u, 0.3 * u]))  # fmt: skip
    assert registry.walk_of(4) is not registry.walk_of(1)
    registry = start()
    registry.observe(11.6, np.array([5]), np.array([[0.58, 0.01]]), (0.3 * u)[None])
    assert registry.walk_of(5) is registry.walk_of(1)


def test_two_walks_of_one_walker_become_one_when_a_track_walks_both() -> None:
    # Track 1 walks along x from 0 to 1 m; track 2, found 2 s later at 1.5 m with its
    # velocity across the line (as a young track's may be), began a walk of its own, which
    # its places then fitted on the same line. Track 3 lies on both: the walks are one.
    registry = WalkRegistry()
    u = np.array([1.0, 0.0])
    for t, i, p in zip(*_places(1, 10.0, 10, np.zeros(2), u, 1.0), strict=True):
        registry.observe(float(t), np.array([i]), p[None], u[None])
    for k, (t, i, p) in enumerate(zip(*_places(2, 13.0, 10, np.array([1.5, 0.0]), u, 0.5),
                                      strict=True)):  # fmt: skip
        velocity = np.array([0.0, 0.5]) if k == 0 else 0.5 * u
        registry.observe(float(t), np.array([i]), p[None], velocity[None])
    first, second = registry.walk_of(1), registry.walk_of(2)
    assert first is not None and second is not None and first is not second
    assert len(registry) == 2 and second.line is not None
    registry.observe(15.0, np.array([3]), np.array([[2.3, 0.01]]), (0.5 * u)[None])
    assert len(registry) == 1
    walk = registry.walk_of(3)
    assert walk is not None and registry.walk_of(1) is walk and registry.walk_of(2) is walk
    assert registry.current(first) is walk and registry.current(second) is walk
    assert set(walk.ids.tolist()) == {1, 2, 3} and walk.line is not None
    assert walk.ends is not None and walk.ends[:, 0].min() == 0.0


def test_two_walks_side_by_side_are_not_merged_by_a_track_between_them() -> None:
    # Two short walks along x, 0.65 m apart (y = 0 and 0.65), each fitted loosely (5 places
    # over 0.3 m: their 3σ a metre out is half a metre). A track 2 m on at y = 0.32 lies
    # within both walks' gates, but not within 0.3 m of both lines: it joins one, and the
    # two walkers' walks stay two.
    registry = WalkRegistry()
    u = np.array([1.0, 0.0])
    for ident, y in ((1, 0.0), (2, 0.65)):
        times, ids, places = _places(ident, 10.0 + 2.0 * ident, 5, np.array([0.0, y]), u, 0.75)
        for t, i, p in zip(times, ids, places, strict=True):
            registry.observe(float(t), np.array([i]), p[None], (0.75 * u)[None])
    assert len(registry) == 2
    registry.observe(16.0, np.array([3]), np.array([[2.0, 0.32]]), (0.75 * u)[None])
    assert len(registry) == 2
    assert registry.walk_of(3) in (registry.walk_of(1), registry.walk_of(2))


def test_a_walker_found_again_by_a_new_track_is_no_longer_kept_where_it_may_be() -> None:
    # Tracked along x (track 5), lost for 2 s (kept on its walk), then found by track 6
    # 1 m on, its velocity 40° off: the memory of track 5's walker goes.
    memory = WalkwayMemory(SPEC, SETTINGS)
    pose = np.array([-3.0, 0.0, 0.0])

    def vector(t: float, ids: list[int], x: float, heading: float) -> EnvironmentView:
        view = walker_view(t, ids)
        if ids:
            view = dataclasses.replace(
                view, position_xy=np.array([[x, 0.0]]),
                velocity_xy=0.5 * np.array([[math.cos(heading), math.sin(heading)]]),
            )  # fmt: skip
        return view

    for j in range(10):
        view = vector(10.0 + 0.1 * j, [5], 1.0 + 0.05 * j, 0.0)
        memory.update(view, capsules_from_view(view, SETTINGS), pose)
    gone = vector(12.0, [], 0.0, 0.0)
    assert set(memory.update(gone, capsules_from_view(gone, SETTINGS), pose).obstacle_id) == {5}
    view = vector(12.5, [6], 2.5, math.radians(40.0))
    memory.update(view, capsules_from_view(view, SETTINGS), pose)
    later = vector(12.6, [6], 2.55, math.radians(40.0))
    memory.update(later, capsules_from_view(later, SETTINGS), pose)
    assert memory.registry.walk_of(6) is memory.registry.walk_of(5)
    assert 5 not in memory._walks
    # Track 6, a mover in only two vectors, is its walk's walker: lost, it is kept (a
    # pillar's track that passed for a mover for two vectors would not be).
    gone = vector(12.7, [], 0.0, 0.0)
    assert set(memory.update(gone, capsules_from_view(gone, SETTINGS), pose).obstacle_id) == {6}
    assert 6 in memory._walks


def test_a_walker_on_a_parallel_walk_beside_is_not_the_lost_one_seen_again() -> None:
    # Two walkers on walks 0.4 m apart along x (random run 67 of seed 0: 0.6 m), each
    # tracked long enough to fit its walk. Walker 5 is lost; walker 7, in view beside where
    # walker 5 may be and walking its way, walks its own walk: walker 5 stays remembered.
    memory = WalkwayMemory(SPEC, SETTINGS)
    pose = np.array([-3.0, -2.0, 0.0])
    for j in range(12):
        view = dataclasses.replace(
            walker_view(10.0 + 0.1 * j, [5, 7]),
            position_xy=np.array([[1.0 + 0.05 * j, 0.0], [3.0 - 0.05 * j, 0.4]]),
            velocity_xy=np.array([[0.5, 0.0], [-0.5, 0.0]]),
        )
        memory.update(view, capsules_from_view(view, SETTINGS), pose)
    five, seven = memory.registry.walk_of(5), memory.registry.walk_of(7)
    assert five is not None and seven is not None and five is not seven
    assert five.line is not None and seven.line is not None
    for j in range(5):
        view = dataclasses.replace(
            walker_view(11.2 + 0.1 * j, [7]),
            position_xy=np.array([[2.4 - 0.05 * j, 0.4]]),
            velocity_xy=np.array([[-0.5, 0.0]]),
        )
        kept = memory.update(view, capsules_from_view(view, SETTINGS), pose)
    assert 5 in set(kept.obstacle_id.tolist()) and 5 in memory._walks


def _walk_along_x(memory: WalkwayMemory, pose: np.ndarray, n: int) -> None:
    """Track 5 walking along y = 0 from x = 1 m at 0.5 m/s for ``n`` vectors from 10 s."""
    for j in range(n):
        view = dataclasses.replace(
            walker_view(10.0 + 0.1 * j, [5]), position_xy=np.array([[1.0 + 0.05 * j, 0.0]])
        )
        memory.update(view, capsules_from_view(view, SETTINGS), pose)


def test_a_walker_seen_again_for_two_vectors_is_still_remembered_when_lost() -> None:
    # Walker 5, tracked for 2 s along x and lost, is found again 0.4 m off its walk's line
    # (off the walk's gate, within the memory's) by track 9 for two vectors, then lost
    # again: track 9 takes over walker 5's memory with its sightings, and is kept.
    memory = WalkwayMemory(SPEC, SETTINGS)
    pose = np.array([-3.0, -2.0, 0.0])
    _walk_along_x(memory, pose, 20)
    gone = walker_view(12.5, [])
    memory.update(gone, capsules_from_view(gone, SETTINGS), pose)
    for j in range(2):
        view = dataclasses.replace(
            walker_view(13.0 + 0.1 * j, [9]), position_xy=np.array([[2.6 + 0.05 * j, 0.4]])
        )
        memory.update(view, capsules_from_view(view, SETTINGS), pose)
    assert memory.registry.walk_of(9) is not memory.registry.walk_of(5)
    assert 5 not in memory._walks
    gone = walker_view(13.3, [])
    kept = memory.update(gone, capsules_from_view(gone, SETTINGS), pose)
    assert set(kept.obstacle_id.tolist()) == {9}


def test_a_short_track_whose_places_and_velocity_agree_shows_which_way_it_walks() -> None:
    # A walk seen from x = 1 to 3 (track 5), then a slow walker's short track on it (0.4 s,
    # 0.3 m/s: 0.12 m, short of the 0.15 m in 0.5 s the longer rule needs) walking +x: it
    # walks on toward x = 3 before it may turn back. Walking against its velocity, or
    # 4 cm in 0.4 s (the places' noise), its way is not known.
    def onward(step_m: float, heading: float) -> float:
        memory = WalkwayMemory(SPEC, SETTINGS)
        pose = np.array([-3.0, -2.0, 0.0])
        _walk_along_x(memory, pose, 41)
        for j in range(5):
            view = dataclasses.replace(
                walker_view(20.0 + 0.1 * j, [8]),
                position_xy=np.array([[1.5 + step_m * j, 0.0]]),
                velocity_xy=0.3 * np.array([[math.cos(heading), math.sin(heading)]]),
            )
            memory.update(view, capsules_from_view(view, SETTINGS), pose)
        assert memory.registry.walk_of(8) is memory.registry.walk_of(5)
        return float(memory.ends[8][1])

    assert onward(0.03, 0.3) > 1.0
    assert onward(0.01, 0.3) == 0.0
    assert onward(0.03, math.pi) == 0.0


def test_a_walker_kept_on_a_fitted_walk_is_as_wide_as_its_line_is_uncertain() -> None:
    # Its track's place is known to 0.2 m (young tracks' are), but its 20 places lie on
    # y = 0 within 2 cm: the walker kept on that line is inflated by 3σ of the line across
    # (its spread and its direction's error out to the capsule's ends), not by 3 x 0.2 m.
    memory = WalkwayMemory(SPEC, SETTINGS)
    pose = np.array([-3.0, -2.0, 0.0])
    rng = np.random.default_rng(3)
    for j in range(20):
        view = dataclasses.replace(
            walker_view(10.0 + 0.1 * j, [5]),
            position_xy=np.array([[1.0 + 0.05 * j, float(rng.normal(0.0, 0.02))]]),
            covariance=np.diag([0.04, 0.04, 0.01, 0.01])[None],
        )
        memory.update(view, capsules_from_view(view, SETTINGS), pose)
    gone = walker_view(12.5, [])
    kept = memory.update(gone, capsules_from_view(gone, SETTINGS), pose)
    line = memory._walks[5].line
    assert line is not None and line.spread_m < 0.03
    assert kept.inflation[0] < 0.3  # 3 x 0.2 m and more by the old rule
    reach = max(np.hypot(*(kept.a[0] - line.centre)), np.hypot(*(kept.b[0] - line.centre)))
    assert kept.inflation[0] == pytest.approx(
        SETTINGS.covariance_sigmas * line.across_sigma_m(reach) + SETTINGS.obstacle_margin_m,
        abs=0.02,
    )


def test_places_that_walk_out_and_back_show_where_the_walker_turned() -> None:
    # A walker pacing x in [0, 2] at 0.5 m/s, its places 0.1 s apart with 2 cm of noise
    # (the tracks' filtered places): the turns are found at the two ends and nowhere else,
    # signed the way it turned; places that only go one way, or back by less than the
    # rise, show none.
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 12.0, 0.1)
    x = 2.0 - np.abs(np.mod(0.5 * t + 1.0, 4.0) - 2.0)  # 1 -> 2 -> 0 -> 2 -> 0 ...
    noisy = x + rng.normal(0.0, 0.02, t.size)
    turn, out = turn_points(noisy, t, 0.2, 3.0, 0.5)
    turns = np.flatnonzero(turn)
    assert len(turns) == 3  # at 2 (t = 2 s), 0 (6 s), 2 (10 s)
    assert t[turns] == pytest.approx([2.0, 6.0, 10.0], abs=0.25)
    assert x[turns] == pytest.approx([2.0, 0.0, 2.0], abs=0.15)
    assert out[turns] == pytest.approx([0.025, -0.025, 0.025])  # half of 0.1 s at 0.5 m/s
    assert not turn_points(0.5 * t[:40], t[:40], 0.2, 3.0, 0.5)[0].any()
    wobble = 0.1 * np.sin(t)  # out and back by 0.2 m: less than the rise either side
    assert not turn_points(wobble, t, 0.25, 3.0, 0.5)[0].any()


def test_a_turn_unseen_between_two_tracks_is_found_further_out_by_the_gap() -> None:
    # Walking down to 0.4 at 0.5 m/s, unseen for 1.2 s, then seen walking back up from 0.4
    # (a new track): it turned somewhere below 0.4, at most 0.3 m below. With a second
    # track's places at the same times (two walkers, or one seen twice), no turn.
    down, up = np.arange(0.0, 2.05, 0.1), np.arange(3.2, 4.25, 0.1)
    t = np.concatenate([down, up])
    x = np.concatenate([1.4 - 0.5 * down, 0.4 + 0.5 * (up - 3.2)])
    turn, out = turn_points(x, t, 0.2, 3.0, 0.5)
    (j,) = np.flatnonzero(turn)
    assert x[j] == pytest.approx(0.4) and out[j] == pytest.approx(-0.3)
    both = np.concatenate([t, up[:2]])
    order = np.argsort(both, kind="stable")
    turn, _ = turn_points(np.concatenate([x, [1.5, 1.4]])[order], both[order], 0.2, 3.0, 0.5)
    assert not turn.any()


def test_a_walk_keeps_the_furthest_turns_each_way_across_its_tracks() -> None:
    # Two tracks of one walker pacing y = 0.5·x at 0.5 m/s: the first turns at the far
    # end, the second (later, once the first is gone from the trail) at the near end. The
    # walk keeps both.
    registry = WalkRegistry()
    u = np.array([2.0, 1.0]) / math.sqrt(5.0)
    for t in np.arange(0.0, 8.0, 0.1):
        track = 3 if t < 4.0 else 8
        s = (1.5 - abs(0.5 * t - 1.5)) if track == 3 else abs(0.5 * t - 3.0) - 0.5
        registry.observe(float(t), np.array([track]), (s * u)[None], (0.5 * u)[None])
        if t < 3.0:  # walking out, not yet back: no turn
            walk = registry.walk_of(3)
            assert walk is not None and walk.turns is None
    walk = registry.walk_of(3)
    assert walk is not None and walk is registry.walk_of(8) and walk.turns is not None
    assert set(walk.ids.tolist()) == {8}  # the first track's places have left the trail
    assert np.sort(walk.turns @ u) == pytest.approx([-0.5, 1.5], abs=0.06)
