"""Walkers kept on their walks after they leave the vector (agent.control.walkways)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agent.control.obstacles import Capsules, capsules_from_view
from agent.control.settings import ControllerSettings
from agent.control.view import EnvironmentView
from agent.control.walkways import WalkwayMemory, profile_clear
from agent.kinematics.vehicle import VehicleSpec
from tests.unit.control.test_obstacle_kernels import walker_view

SPEC = VehicleSpec()
SETTINGS = ControllerSettings()
POSE = np.array([-2.0, 0.0, 0.0])  # the vehicle 3 m behind the walker, facing it


def runs(capsules: Capsules) -> tuple[np.ndarray, np.ndarray]:
    """The remembered walkers' runs of possible places as (starts, ends): each run comes as
    a chain of capsules, each beginning where the one before ends."""
    a, b = capsules.a, capsules.b
    first = np.ones(len(a), dtype=bool)
    first[1:] = ~np.all(np.isclose(a[1:], b[:-1], atol=1e-9), axis=1)
    last = np.roll(first, -1)
    return a[first], b[last]


def _update(memory: WalkwayMemory, view: EnvironmentView) -> tuple[np.ndarray, np.ndarray]:
    return runs(memory.update(view, capsules_from_view(view, SETTINGS), POSE))


def _sighted(memory: WalkwayMemory, t: float, ids: list[int], pose: np.ndarray = POSE) -> Capsules:
    """The walkers ``ids`` in the vectors up to ``t``, as many as a walker must be to be kept
    (``walkway_min_sightings``, 0.1 s apart); the last update's capsules."""
    n = SETTINGS.walkway_min_sightings
    for j in range(n):
        view = walker_view(t - 0.1 * (n - 1 - j), ids)
        ghost = memory.update(view, capsules_from_view(view, SETTINGS), pose)
    return ghost


def test_a_walker_that_leaves_is_kept_growing_along_its_line_both_ways() -> None:
    memory = WalkwayMemory(SPEC, SETTINGS)
    assert not len(_sighted(memory, 10.0, [7]))  # in the vector: nothing added
    # 1 s later, gone from the vector: within 0.5 m of (1, 0) along x, either way, swept
    # by the braking horizon's walk.
    a, b = _update(memory, walker_view(11.0, []))
    sweep = 0.5 * SETTINGS.mover_horizon_s
    np.testing.assert_allclose(a, [[1.0 - 0.5 - sweep, 0.0]], atol=1e-9)
    np.testing.assert_allclose(b, [[1.0 + 0.5 + sweep, 0.0]], atol=1e-9)
    assert memory.walkers.age[0] == pytest.approx(0.5 / 0.5)
    # 5 s on: 3 m either way at most (walkway_reach_m).
    a, b = _update(memory, walker_view(16.0, []))
    np.testing.assert_allclose(a[0, 0], 1.0 - SETTINGS.walkway_reach_m - sweep, atol=1e-9)
    np.testing.assert_allclose(b[0, 0], 1.0 + SETTINGS.walkway_reach_m + sweep, atol=1e-9)


def test_the_places_to_look_at_are_where_the_lost_walker_may_be() -> None:
    memory = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory, 10.0, [7])
    # In the vector: nothing to look for.
    assert memory.possible_places(POSE[:2], 3.0, 48).shape == (0, 2)
    _update(memory, walker_view(11.0, []))
    # Lost 1 s ago at (1, 0) walking along x at 0.5 m/s: its possible cells, 0.5 m either
    # way, nearest the vehicle (at x = -2) first.
    places = memory.possible_places(POSE[:2], 4.0, 48)
    np.testing.assert_allclose(places[:, 1], 0.0, atol=1e-9)
    np.testing.assert_allclose(places[:, 0], np.arange(0.5, 1.55, 0.1), atol=1e-9)
    # Out of reach, and at most the limit.
    np.testing.assert_allclose(memory.possible_places(POSE[:2], 2.75, 48)[:, 0], [0.5, 0.6, 0.7])
    assert memory.possible_places(POSE[:2], 4.0, 2).shape == (2, 2)


def test_the_inflation_grows_with_the_direction_error_over_the_reach() -> None:
    memory = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory, 10.0, [7])
    capsules = memory.update(
        walker_view(11.0, []), capsules_from_view(walker_view(11.0, []), SETTINGS), POSE
    )
    # σ 2 cm in place, 1 cm/s across a 0.5 m/s walk (0.02 rad), reach 0.5 + 0.75 m.
    reach = 0.5 + 0.5 * SETTINGS.mover_horizon_s
    want = 3.0 * math.hypot(0.02, 0.02 * reach) + SETTINGS.obstacle_margin_m
    assert capsules.inflation[0] == pytest.approx(want)
    # In 0.5 m pieces, each for its own reach: the middle one's is 0.25 m.
    assert len(capsules) == 5
    middle = 3.0 * math.hypot(0.02, 0.02 * 0.25) + SETTINGS.obstacle_margin_m
    assert capsules.inflation[2] == pytest.approx(middle)
    assert capsules.radius[0] == pytest.approx(0.2)
    assert capsules.moving.all() and set(capsules.obstacle_id) == {7}


def test_a_walker_lost_while_it_turned_is_kept_growing_at_its_pace() -> None:
    """Seen walking at 0.5 m/s, then last at 0.1 m/s (turning back at its walk's end): kept,
    its places grow at the 0.5 m/s it walked, not the 0.1 m/s it was last seen at."""
    memory = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory, 10.0, [7])
    slow = dataclasses.replace(walker_view(10.1, [7]), velocity_xy=np.array([[0.1, 0.0]]))
    memory.update(slow, capsules_from_view(slow, SETTINGS), POSE)
    a, b = _update(memory, walker_view(11.1, []))
    sweep = 0.5 * SETTINGS.mover_horizon_s
    np.testing.assert_allclose(a, [[1.0 - 0.5 - sweep, 0.0]], atol=1e-9)
    np.testing.assert_allclose(b, [[1.0 + 0.5 + sweep, 0.0]], atol=1e-9)


def test_cells_seen_clear_leave_the_set_less_the_walk_since() -> None:
    """The seen profile holds clear 1.65 m about the centre of scanning (at x = -1.7):
    the cells up to x = -0.1 (of -1 ... 3, where it may be by then); but the walker could
    have walked 0.25 m (0.5 s at 0.5 m/s) into what those scans saw, so only the cells
    more than 3 cells from the unseen go, up to x = -0.4."""
    memory = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory, 10.0, [7])
    _update(memory, walker_view(14.0, []))  # by now anywhere within 2 m either way
    seen = dataclasses.replace(
        walker_view(14.1, []), seen_range_m=np.full(360, 1.65), seen_far_m=np.zeros(360),
        seen_end_hit=np.zeros(360, dtype=np.uint8),
    )  # fmt: skip
    a, b = _update(memory, seen)
    sweep = 0.5 * SETTINGS.mover_horizon_s
    assert a[0, 0] == pytest.approx(-0.3 - sweep)
    assert b[0, 0] == pytest.approx(3.0 + sweep)


def test_it_is_forgotten_when_cleared_seen_again_or_old() -> None:
    memory = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory, 10.0, [7])
    # Everything seen clear far round: no place left for it.
    clear = dataclasses.replace(
        walker_view(10.5, []), seen_range_m=np.full(360, 2.5), seen_far_m=np.zeros(360),
        seen_end_hit=np.zeros(360, dtype=np.uint8),
    )  # fmt: skip
    memory2 = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory2, 10.0, [7])
    far = dataclasses.replace(clear, position_xy=np.zeros((0, 2)))
    _update(memory2, far)
    assert len(memory2) == 1  # POSE is 3 m off: its far cells lie beyond 2.5 m
    near_pose = np.array([-0.3, 0.0, 0.0])
    memory3 = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory3, 10.0, [7], near_pose)
    memory3.update(clear, capsules_from_view(clear, SETTINGS), near_pose)
    assert len(memory3) == 0
    # A new track on the same line where it may be: the same walker.
    _update(memory, walker_view(11.0, []))
    _sighted(memory, 11.5, [8])
    assert set(memory._walks) == {8}
    # Not seen for walkway_memory_s: forgotten.
    _update(memory, walker_view(12.0, []))
    a, _ = _update(memory, walker_view(11.5 + SETTINGS.walkway_memory_s + 0.01, []))
    assert not len(a) and len(memory) == 0


def test_a_mover_of_too_few_vectors_is_not_kept() -> None:
    """A track that was a mover in fewer than ``walkway_min_sightings`` vectors (a static
    pillar's track whose velocity flickered) is forgotten when it leaves; one more, kept."""
    n = SETTINGS.walkway_min_sightings
    for seen, kept in ((n - 1, 0), (n, 1)):
        memory = WalkwayMemory(SPEC, SETTINGS)
        for j in range(seen):
            _update(memory, walker_view(10.0 + 0.1 * j, [7]))
        a, _ = _update(memory, walker_view(11.0, []))
        assert len(a) == kept and len(memory) == kept


def test_static_obstacles_are_not_remembered() -> None:
    memory = WalkwayMemory(SPEC, SETTINGS)
    still = dataclasses.replace(walker_view(20.0, [3]), velocity_xy=np.zeros((1, 2)))
    _update(memory, still)
    a, _ = _update(memory, walker_view(20.5, []))
    assert not len(a)


def test_profile_clear_reads_sectors_centred_on_their_bearings() -> None:
    view = walker_view(0.0, [])
    ranges = np.zeros(360)
    ranges[180] = 2.0  # the sector centred on bearing 0 (±0.5°)
    pose = np.array([0.0, 0.0, 0.0])
    points = np.array([[1.3, 0.0], [1.3, 0.0075], [1.3, 0.02], [2.5, 0.0], [1.3, -0.0075]])
    got = profile_clear(view, ranges, pose, 0.3, points)
    # 1 m from the centre of scanning at (0.3, 0): 0.43° and −0.43° inside, 1.15° not.
    assert got.tolist() == [True, True, False, False, True]


def _out_and_back(memory: WalkwayMemory, pose: np.ndarray) -> float:
    """Walker 5 seen walking along x from 0 to 2 and back to 1.05 (0.5 m/s, a vector every
    0.1 s from t = 10 s); the time of the next vector."""
    t, x, step = 10.0, 0.0, 0.05
    for j in range(60):
        if j == 40:
            step = -0.05
        view = dataclasses.replace(
            walker_view(t, [5]), position_xy=np.array([[x, 0.0]]),
            velocity_xy=np.array([[10.0 * step, 0.0]]),
        )  # fmt: skip
        memory.update(view, capsules_from_view(view, SETTINGS), pose)
        t, x = t + 0.1, x + step
    assert x == pytest.approx(1.0)
    return t


def test_a_lost_walker_walks_on_and_turns_back_only_where_its_walk_may_end() -> None:
    # A walker seen walking along x from 0 to 2 and back to 1 (0.5 m/s), lost there walking
    # toward 0 (the vehicle at (-2, -2)). It walks on; it may turn back only at or beyond
    # where its walk was seen to end (x = 0, less two cells of slack), so for a while it
    # cannot be anywhere above x = 1, where a walker that might turn back at once (its way
    # unknown) would be; and then only as far as it could have come back from that end.
    memory = WalkwayMemory(SPEC, SETTINGS)
    pose = np.array([-2.0, -2.0, 0.0])
    t = _out_and_back(memory, pose)

    def places_after(seconds: float) -> np.ndarray:
        nonlocal t
        for _ in range(round(seconds / 0.1)):  # a vector every 0.1 s, the walker in none
            gone = walker_view(t, [])
            memory.update(gone, capsules_from_view(gone, SETTINGS), pose)
            t += 0.1
        return memory.possible_places(pose[:2], 10.0, 200)[:, 0]

    # Lost at (1.05, 0) (its last place): 1 s on, only toward 0.
    one = places_after(1.0)
    assert one.min() == pytest.approx(0.55, abs=0.06) and one.max() == pytest.approx(1.05)
    # 3 s on: on to -0.45, and back from its walk's end (0.25 at the earliest, 1.6 s
    # after it was lost) by at most 0.7 m: none above 0.95 (and a cell: the set grows a
    # cell a vector).
    three = places_after(2.0)
    assert three.min() == pytest.approx(-0.45, abs=0.06)
    assert three.max() <= 1.06


def test_a_lost_walker_walks_no_further_than_where_its_walk_was_seen_to_turn() -> None:
    # A walker seen walking along x from 0 to 2, turning there, and back to 1 (0.5 m/s),
    # lost walking toward 0. It may walk on past 0 (it was never seen to turn there) and
    # come back, but not beyond 2 (and two cells of slack), where it turned: neither its
    # places nor its capsules, however long it is kept.
    memory = WalkwayMemory(SPEC, SETTINGS)
    pose = np.array([-2.0, -2.0, 0.0])
    t = _out_and_back(memory, pose)
    # In view, it turns back there too (its capsule is not swept past: walk_lines' tests).
    assert memory.turns[5][:, 0] == pytest.approx([2.2], abs=0.06)
    highest, lowest = [], []
    for _ in range(150):  # 15 s, a vector every 0.1 s, the walker in none
        gone = walker_view(t, [])
        capsules = memory.update(gone, capsules_from_view(gone, SETTINGS), pose)
        t += 0.1
        places = memory.possible_places(pose[:2], 10.0, 200)[:, 0]
        highest.append(places.max())
        lowest.append(places.min())
        assert max(capsules.a[:, 0].max(), capsules.b[:, 0].max()) <= 2.0 + 0.2 + 0.06
    assert max(highest) == pytest.approx(2.2, abs=0.06)  # it came back up as far as it may
    assert min(lowest) < -1.0  # and walked on past 0, where it was not seen to turn


_WALK_U = np.array([math.cos(0.7), math.sin(0.7)])  # a walk's line through (1, 0)


def _walk_9(memory: WalkwayMemory, t: float, j: int) -> None:
    """Track 9 at ``t``, at step ``j`` of 11 of a 0.5 m walk along :data:`_WALK_U` at
    0.5 m/s that ends at (1, 0)."""
    place = np.array([1.0, 0.0]) + (0.05 * j - 0.5) * _WALK_U
    view = dataclasses.replace(
        walker_view(t, [9]), position_xy=place[None], velocity_xy=(0.5 * _WALK_U)[None]
    )
    memory.update(view, capsules_from_view(view, SETTINGS), POSE)


def test_a_walker_lost_unfitted_takes_the_line_of_a_walk_fitted_through_where_it_was() -> None:
    # A walker glimpsed standing-still-fast at (1, 0) (its places fit no line) is lost and
    # kept on its velocity's line, at the inflation cap. Another track then walks a line
    # through (1, 0), 40° off that velocity: the lost walker is that walk's walker, kept
    # on its line while the new track is gone, and forgotten while it is in the vector.
    memory = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory, 10.0, [5])
    lost = _update(memory, walker_view(10.5, []))
    assert len(memory) == 1 and memory._walks[5].line is None
    for j in range(11):
        _walk_9(memory, 11.0 + 0.1 * j, j)
        if j < 4:  # not yet fitted: still kept as it was
            assert 5 in memory._walks and memory._walks[5].line is None
    assert 5 not in memory._walks  # its walk's walker is in the vector: found again
    assert len(lost[0]) > 0


def test_a_walker_lost_unfitted_on_a_known_walk_is_kept_on_its_line() -> None:
    # A walk fitted along u through (1, 0) by a track that has left; then a new track at
    # (1, 0) whose velocity crosses that line (the tracks' velocities are tens of degrees
    # off: it does not join the walk), lost before its own places fit a line. It is kept
    # on the walk's line, inflated by the line's σ, not on its velocity's at the cap.
    memory = WalkwayMemory(SPEC, SETTINGS)
    u = _WALK_U
    for j in range(11):
        _walk_9(memory, 10.0 + 0.1 * j, j)
    t = 11.1
    _update(memory, walker_view(t, []))  # 9 leaves
    crossing = np.array([[-0.5 * u[1], 0.5 * u[0]]])  # its velocity across the line
    for j in range(SETTINGS.walkway_min_sightings):
        view = dataclasses.replace(walker_view(t + 0.1 * j, [5]), velocity_xy=crossing)
        memory.update(view, capsules_from_view(view, SETTINGS), POSE)
    gone = walker_view(t + 1.0, [])
    capsules = memory.update(gone, capsules_from_view(gone, SETTINGS), POSE)
    walk = memory._walks[5]
    assert walk.line is not None and abs(float(walk.direction @ u)) == pytest.approx(1.0)
    mine = capsules.obstacle_id == 5
    assert mine.any() and capsules.inflation[mine].max() < 0.5
    d = capsules.b[mine] - capsules.a[mine]
    assert np.all(np.abs(d @ np.array([-u[1], u[0]])) < 1e-9)  # along the walk's line


def test_a_walker_whose_own_track_stands_seen_where_it_is_is_forgotten() -> None:
    """A static post's track that passed for a mover in enough vectors to be kept, then is
    in the vector again, static and seen in the newest scans (``seen_age_s`` 0), is
    forgotten once it has stood so for ``walkway_standing_s``; while its track only coasts
    (its sighting older than ``walkway_seen_age_s``), or the vector gives no ages, it is
    kept."""
    standing = SETTINGS.walkway_standing_s

    def still(t: float, age: float | None) -> EnvironmentView:
        view = dataclasses.replace(walker_view(t, [7]), velocity_xy=np.zeros((1, 2)))
        return view if age is None else dataclasses.replace(view, seen_age_s=np.array([age]))

    for age, kept in ((0.0, 0), (SETTINGS.walkway_seen_age_s + 0.1, 1), (None, 1)):
        memory = WalkwayMemory(SPEC, SETTINGS)
        _sighted(memory, 10.0, [7])
        t = 10.1
        _update(memory, still(t, age))
        assert len(memory) == 1  # not yet: a walker turning at its walk's end is slow too
        while t < 10.1 + standing + 0.15:
            t += 0.1
            _update(memory, still(t, age))
        assert len(memory) == kept, age
    # A stand broken by a vector in which it did not stand starts over.
    memory = WalkwayMemory(SPEC, SETTINGS)
    _sighted(memory, 10.0, [7])
    _update(memory, still(10.1, 0.0))
    _update(memory, still(10.1 + standing - 0.05, 1.0))
    _update(memory, still(10.1 + standing + 0.05, 0.0))
    assert len(memory) == 1


def test_the_walkers_in_view_carry_how_far_they_walk_on_and_where_their_walk_ends() -> None:
    """Walker 5, seen out along x from 0 to 2, turning there, and back to 1: walking toward
    0 (its walk seen to reach x = 0, two cells of slack), it walks on 0.8 m or more before
    it may turn; its walk ends at 2.2 behind it (where it turned, two cells of slack), and
    ahead where it was never seen to turn, not at all."""
    memory = WalkwayMemory(SPEC, SETTINGS)
    _out_and_back(memory, np.array([-2.0, -2.0, 0.0]))
    heading, onward, lo, hi = memory.ends[5]
    np.testing.assert_allclose(heading, [-1.0, 0.0], atol=1e-6)
    assert onward == pytest.approx(1.05 - 0.2, abs=0.06)
    assert lo == pytest.approx(-(2.2 - 1.0), abs=0.11) and math.isinf(hi)
