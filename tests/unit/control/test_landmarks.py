"""The odometry's drift measured on static obstacles (agent.control.landmarks)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
import pytest

from agent.control.landmarks import DriftEstimate, DriftSettings
from agent.control.view import EnvironmentView

# Static obstacles in the world: three posts (cylinders), a corner and a wall (segment).
POSTS = np.array([[2.0, 1.0], [3.0, -1.5], [1.0, 2.5]])
CORNER = np.array([4.0, 0.5])
WALL = np.array([[-1.0, 3.0], [3.0, 3.0]])


def _transform(xy: np.ndarray, t: tuple[float, float], theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.asarray(xy) @ np.array([[c, -s], [s, c]]).T + np.array(t)


def _view(
    stamp: float, t: tuple[float, float], theta: float, rng: np.random.Generator,
    sigma: float = 0.01, moved: np.ndarray | None = None, age: np.ndarray | None = None,
) -> EnvironmentView:  # fmt: skip
    """The obstacles where ``odom`` puts them when the world lies at ``(t, θ)`` in it, each
    off by Gaussian noise of ``sigma`` (its stated σ); ``moved`` replaces the posts' world
    places (a track that took another obstacle)."""
    posts = POSTS if moved is None else moved
    pts = _transform(np.concatenate([posts, CORNER[None]]), t, theta)
    pts = pts + rng.normal(0.0, sigma, pts.shape)
    wall = _transform(WALL, t, theta) + rng.normal(0.0, sigma, (1, 2))  # across it, mostly
    k = len(pts) + 1
    cov = np.tile(np.diag([sigma**2, sigma**2, 1e-4, 1e-4]), (k, 1, 1))
    extent = np.zeros((k, 4))
    extent[: len(posts), 0] = 0.1
    extent[-1] = wall.ravel()
    bearings = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    return EnvironmentView(
        stamp_s=stamp, valid_for_s=0.3, sensor_ok=True,
        obstacle_id=np.arange(k, dtype=np.int64) + 10,
        kind=np.array([3] * len(posts) + [1, 0], dtype=np.uint8),
        position_xy=np.concatenate([pts, wall.mean(axis=0)[None]]),
        velocity_xy=np.zeros((k, 2)), covariance=cov, extent=extent,
        reflectivity=np.ones(k), free_bearing_rad=bearings, free_range_m=np.zeros(360),
        across_sigma_m=np.full(k, sigma), seen_age_s=np.zeros(k) if age is None else age,
    )  # fmt: skip


def test_the_drift_is_recovered_from_obstacles_anchored_at_the_start() -> None:
    rng = np.random.default_rng(3)
    est = DriftEstimate()
    est.update(_view(0.0, (0.0, 0.0), 0.0, rng), np.zeros(5, dtype=bool))
    assert len(est) == 5
    # The odometry drifts: 6° and 0.2 m. Each vector's obstacles show it.
    truth_t, truth_theta = (0.2, -0.1), math.radians(6.0)
    for j in range(1, 21):
        f = j / 20.0
        est.update(
            _view(0.1 * j, (f * truth_t[0], f * truth_t[1]), f * truth_theta, rng),
            np.zeros(5, dtype=bool),
        )
    # Tolerance: 1 cm noise on five obstacles 1-4 m out, anchored with the same noise:
    # σ of θ about 0.3°, of t about 1 cm; 4σ.
    assert est.theta == pytest.approx(truth_theta, abs=math.radians(1.2))
    np.testing.assert_allclose(est.t, truth_t, atol=0.04)
    goal = np.array([5.0, 2.0])
    np.testing.assert_allclose(est.to_odom(goal), _transform(goal, truth_t, truth_theta), atol=0.06)
    assert est.used == 5


def test_an_obstacle_that_jumps_is_gated_out_then_anchored_anew() -> None:
    rng = np.random.default_rng(4)
    est = DriftEstimate()
    est.update(_view(0.0, (0.0, 0.0), 0.0, rng), np.zeros(5, dtype=bool))
    moved = POSTS.copy()
    moved[0] += [0.6, 0.0]  # its track now follows another post
    used = []
    for j in range(1, 8):
        est.update(_view(0.1 * j, (0.0, 0.0), 0.0, rng, moved=moved), np.zeros(5, dtype=bool))
        used.append(est.used)
        assert abs(est.theta) < math.radians(0.5)
        np.testing.assert_allclose(est.t, [0.0, 0.0], atol=0.02)
    # Gated out of each fit until forgotten (drop_after), then anchored where it now is.
    drop = est.settings.drop_after
    assert used[:drop] == [4] * drop and used[-1] == 5
    assert len(est) == 5
    np.testing.assert_allclose(est._anchors.w[est._index[10]], moved[0], atol=0.04)


def test_movers_and_vague_obstacles_are_not_anchored() -> None:
    rng = np.random.default_rng(5)
    est = DriftEstimate()
    moving = np.array([True, False, False, False, False])
    est.update(_view(0.0, (0.0, 0.0), 0.0, rng, sigma=0.01), moving)
    assert len(est) == 4
    est2 = DriftEstimate()
    est2.update(_view(0.0, (0.0, 0.0), 0.0, rng, sigma=0.05), np.zeros(5, dtype=bool))
    assert len(est2) == 0  # σ 5 cm: more than anchor_sigma_m
    # With nothing anchored, the world is where odometry puts it.
    np.testing.assert_allclose(est2.to_odom(np.array([1.0, 2.0])), [1.0, 2.0])


def test_only_obstacles_the_newest_scan_updated_are_fitted() -> None:
    # Drifted by 5°, but the posts and the corner coast (last seen 1 s ago, where the
    # odometry put them then): only the wall is fresh.
    rng = np.random.default_rng(6)
    est = DriftEstimate()
    est.update(_view(0.0, (0.0, 0.0), 0.0, rng), np.zeros(5, dtype=bool))
    coasting = np.array([1.0, 1.0, 1.0, 1.0, 0.0])
    stale = _view(1.0, (0.0, 0.0), 0.0, rng, age=coasting)
    drifted = _view(1.0, (0.0, 0.0), math.radians(5.0), rng, age=coasting)
    stale_posts = dataclasses.replace(
        drifted, position_xy=np.concatenate([stale.position_xy[:4], drifted.position_xy[4:]])
    )
    est.update(stale_posts, np.zeros(5, dtype=bool))
    assert est.used == 1
    # The wall's direction alone shows the turn (the stale posts would have held it at 0).
    assert est.theta == pytest.approx(math.radians(5.0), abs=math.radians(0.5))
    # Seen again by the newest scan, all agree.
    est.update(_view(1.1, (0.0, 0.0), math.radians(5.0), rng), np.zeros(5, dtype=bool))
    assert est.used == 5
    assert est.theta == pytest.approx(math.radians(5.0), abs=math.radians(0.5))


def _wall_only(stamp: float, theta: float, tilt: float) -> EnvironmentView:
    """The wall alone, where ``odom`` puts it when the world is turned ``theta`` in it, its
    measured direction off by ``tilt`` (about its middle); its stated σ 1 cm at the ends."""
    view = _view(stamp, (0.0, 0.0), theta, np.random.default_rng(0), sigma=1e-9)
    wall = view.extent[-1].reshape(2, 2)
    mid = wall.mean(axis=0)
    wall = _transform(wall - mid, (float(mid[0]), float(mid[1])), tilt)
    keep = np.array([False] * 4 + [True])
    return dataclasses.replace(
        view, obstacle_id=view.obstacle_id[keep], kind=view.kind[keep],
        position_xy=view.position_xy[keep], velocity_xy=view.velocity_xy[keep],
        covariance=view.covariance[keep], extent=wall.ravel()[None],
        reflectivity=view.reflectivity[keep], across_sigma_m=np.array([0.01]),
        seen_age_s=np.zeros(1),
    )  # fmt: skip


def test_standing_still_the_heading_holds_and_driving_it_follows_the_walls() -> None:
    # The wall's direction σ: at most 1 cm over 2 m (0.3°); each vector's off by 0.3° one
    # way or the other. Standing, the estimate keeps what it had (the odometry did not
    # move: it cannot have drifted); weak-priored, it jumped with each vector.
    est, weak = DriftEstimate(), DriftEstimate()
    pose = np.zeros(3)
    est.update(_wall_only(0.0, 0.0, 0.0), np.zeros(1, dtype=bool), pose)
    weak.update(_wall_only(0.0, 0.0, 0.0), np.zeros(1, dtype=bool))
    tilt = math.radians(0.3)
    for j in range(1, 11):
        view = _wall_only(0.1 * j, 0.0, tilt * (-1) ** j)
        est.update(view, np.zeros(1, dtype=bool), pose)
        weak.update(view, np.zeros(1, dtype=bool))
        assert abs(est.theta) < math.radians(0.05)
    assert abs(weak.theta) > math.radians(0.25)
    # Driving 3 m, the world turns 3° in odom: the estimate follows (within 0.3°).
    for j in range(1, 31):
        pose = np.array([0.1 * j, 0.0, 0.0])
        est.update(
            _wall_only(1.0 + 0.1 * j, math.radians(0.1 * j), 0.0), np.zeros(1, dtype=bool), pose
        )
    assert est.theta == pytest.approx(math.radians(3.0), abs=math.radians(0.3))


def test_the_place_is_dead_reckoned_and_the_anchors_give_the_heading() -> None:
    """``dead_reckon_place``: the obstacles all seen 0.2 m further along x while the
    odometry says the vehicle stood still move the fitted place, not the dead reckoned one
    (a chain of anchors carries its errors into the place; the odometry's steps turned by a
    good heading are off only by the wheels' scale error). Both take the heading the
    obstacles show; and driving on, the dead reckoned place follows the odometry's steps
    turned back by that heading."""
    rng = np.random.default_rng(7)
    moving = np.zeros(5, dtype=bool)
    fitted = DriftEstimate(DriftSettings(dead_reckon_place=False))
    reckoned = DriftEstimate(DriftSettings(dead_reckon_place=True))
    still = np.zeros(3)
    for est in (fitted, reckoned):
        est.update(_view(0.0, (0.0, 0.0), 0.0, rng, sigma=0.002), moving, still)
        for j in range(1, 11):
            est.update(_view(0.1 * j, (0.2, 0.0), 0.0, rng, sigma=0.002), moving, still)
    # Tolerances: 2 mm noise on five obstacles, a few mm on the place.
    np.testing.assert_allclose(fitted.t, [0.2, 0.0], atol=0.01)
    np.testing.assert_allclose(reckoned.t, [0.0, 0.0], atol=1e-9)
    # The heading: the obstacles turned by 3° about the origin, where the vehicle stands.
    theta = math.radians(3.0)
    for j in range(11, 31):
        reckoned.update(_view(0.1 * j, (0.0, 0.0), theta, rng, sigma=0.002), moving, still)
    assert reckoned.theta == pytest.approx(theta, abs=math.radians(0.3))
    np.testing.assert_allclose(reckoned.t, [0.0, 0.0], atol=1e-9)
    # Driving 1 m along the odometry's heading (3° off the world's x), nothing in view:
    # the vehicle is 1 m along the world's x, and the world's origin stays put in odom.
    empty = dataclasses.replace(
        _view(3.1, (0.0, 0.0), theta, rng),
        obstacle_id=np.zeros(0, dtype=np.int64), kind=np.zeros(0, dtype=np.uint8),
        position_xy=np.zeros((0, 2)), velocity_xy=np.zeros((0, 2)),
        covariance=np.zeros((0, 4, 4)), extent=np.zeros((0, 4)), reflectivity=np.zeros(0),
        across_sigma_m=np.zeros(0), seen_age_s=np.zeros(0),
    )  # fmt: skip
    held = reckoned.theta
    step = np.array([math.cos(theta), math.sin(theta)])
    for j in range(1, 11):
        pose = np.array([*(0.1 * j * step), theta])
        reckoned.update(dataclasses.replace(empty, stamp_s=3.1 + 0.1 * j), np.zeros(0, bool), pose)
    np.testing.assert_allclose(reckoned.t, [0.0, 0.0], atol=1e-9)
    goal_ahead = reckoned.to_odom(np.array([2.0, 0.0]))  # 1 m on along the world's x
    np.testing.assert_allclose(goal_ahead, 2.0 * np.array([math.cos(held), math.sin(held)]))


def test_the_wheels_scale_error_is_measured_on_the_anchors_and_taken_out_of_the_place() -> None:
    """Wheels that read 2 % short: driving 6 m along a row of posts, each post, anchored
    when first seen, shows it (it drifts back in ``odom`` by 2 % of the travel since); the
    estimate finds the error and the dead reckoned place comes out near the truth, where
    the odometry's own is 12 cm short. Tolerances: posts seen to 5 mm (σ) over 2 m of
    travel each measure the error to about 0.25 % (σ); 30 of them, to 0.1 %: 0.5 % is 5σ."""
    rng = np.random.default_rng(11)
    delta = 0.02  # true distance per unit reading, minus one
    posts = np.stack([np.arange(0.5, 8.0, 0.25), np.where(np.arange(30) % 2, 1.0, -1.0)], 1)
    est = DriftEstimate()
    sigma = 0.005
    for j in range(0, 121):
        x_true = 0.05 * j
        x_odom = x_true / (1.0 + delta)
        seen = np.flatnonzero(np.abs(posts[:, 0] - x_true - 1.0) <= 1.0)  # 0-2 m ahead
        k = seen.size
        pts = posts[seen] - [x_true, 0.0] + [x_odom, 0.0] + rng.normal(0.0, sigma, (k, 2))
        view = _posts_view(0.1 * j, pts, seen, sigma)
        est.update(view, np.zeros(k, dtype=bool), np.array([x_odom, 0.0, 0.0]))
    assert est.scale == pytest.approx(delta, abs=0.005)
    assert est.scale_sigma < 0.005
    # The vehicle's place in the world: where the odometry is, less t.
    place = np.array([6.0 / (1.0 + delta), 0.0]) - est.t
    assert abs(place[0] - 6.0) < 0.04  # the odometry alone: 0.118 m short
    unscaled = DriftEstimate(DriftSettings(estimate_scale=False))
    assert unscaled.scale == 0.0


def _posts_view(stamp: float, xy: np.ndarray, ids: np.ndarray, sigma: float) -> EnvironmentView:
    k = len(ids)
    return EnvironmentView(
        stamp_s=stamp, valid_for_s=0.3, sensor_ok=True, obstacle_id=ids.astype(np.int64) + 10,
        kind=np.full(k, 3, dtype=np.uint8), position_xy=xy.reshape(k, 2),
        velocity_xy=np.zeros((k, 2)),
        covariance=np.tile(np.diag([sigma**2, sigma**2, 1e-4, 1e-4]), (k, 1, 1)),
        extent=np.tile([0.05, 0.0, 0.0, 0.0], (k, 1)), reflectivity=np.ones(k),
        free_bearing_rad=np.linspace(-np.pi, np.pi, 360, endpoint=False),
        free_range_m=np.zeros(360), across_sigma_m=np.full(k, sigma), seen_age_s=np.zeros(k),
    )  # fmt: skip


def _curving_drive(
    est: DriftEstimate, posts: np.ndarray, rate: float, steps: int,
    seen_from: Callable[[float], np.ndarray], rng: np.random.Generator,
) -> None:  # fmt: skip
    """Drive ``est`` 5 cm a step along the odometry's x while the truth curves: the
    odometry's heading less the truth's grows by ``rate`` per metre. ``seen_from(s)`` picks
    the posts in view at ``s`` m (their indices); each is seen to 5 mm."""
    x_true = np.zeros(2)
    for j in range(steps + 1):
        s = 0.05 * j
        theta = rate * s
        if j:
            yaw_true = -rate * (s - 0.025)  # the step's mid-point
            x_true = x_true + 0.05 * np.array([math.cos(yaw_true), math.sin(yaw_true)])
        seen = seen_from(s)
        c, sn = math.cos(theta), math.sin(theta)
        rel = (posts[seen] - x_true) @ np.array([[c, -sn], [sn, c]]).T
        xy = rel + np.array([s, 0.0]) + rng.normal(0.0, 0.005, rel.shape)
        est.update(_posts_view(0.1 * j, xy, seen, 0.005), np.zeros(seen.size, bool),
                   np.array([s, 0.0, 0.0]))  # fmt: skip


def test_the_headings_drift_per_metre_is_learnt_and_carries_it_where_nothing_is_seen() -> None:
    """Wheels whose right reads 3.5 % short of the left (0.07 rad/m on a 0.5 m track): the
    odometry drives straight, the truth curves. Posts beside the first 4 m show the heading
    drifting; over the next 2 m nothing is in view. With the drift's rate learnt, the
    heading is carried on (within 1.5°: 0.8° measured); held, it is 2 m × 0.07 rad/m = 8°
    off. Posts seen to 5 mm give the heading to a few tenths of a degree a vector, the rate
    to a few thousandths of a rad/m over 4 m."""
    rng = np.random.default_rng(5)
    rate = 0.07  # rad per metre: θ = yaw_odom − yaw_true grows by this
    posts = np.stack([np.arange(0.5, 6.0, 0.3), np.where(np.arange(19) % 2, 0.8, -0.8)], 1)
    errors = {}
    for learn in (True, False):
        est = DriftEstimate(DriftSettings(estimate_rates=learn, estimate_scale=False))
        _curving_drive(
            est, posts, rate, 120,
            lambda s: np.flatnonzero((np.abs(posts[:, 0] - s - 1.0) <= 1.0) & (s <= 4.0)), rng,
        )  # fmt: skip
        errors[learn] = abs(est.theta - rate * 6.0)
    assert errors[True] < math.radians(1.5)
    assert errors[False] > math.radians(6.0)


def test_one_post_at_a_time_gives_the_heading_from_the_dead_reckoned_place() -> None:
    """The head sees one or two things at a time. Driving 4 m past posts 1 m apart, one in
    view at a time, with the odometry's heading drifting 0.05 rad/m (11° in all): each
    post's bearing from the dead reckoned place gives the heading, which follows to within
    3.5° (2.7° measured: each post, anchored with the heading of its day, hands that error
    on). With the weak prior on the place, the posts' shifts went into it and the heading
    stayed where it began (0.02°, 11.5° off). The rates are not learnt here."""
    rng = np.random.default_rng(9)
    rate = 0.05
    posts = np.stack([np.arange(1.0, 6.0, 1.0), np.full(5, 0.7)], 1)
    est = DriftEstimate(DriftSettings(estimate_rates=False, estimate_scale=False))

    def nearest_ahead(s: float) -> np.ndarray:
        ahead = posts[:, 0] - s
        return np.flatnonzero((ahead > 0.3) & (ahead <= 1.3))[:1]

    _curving_drive(est, posts, rate, 80, nearest_ahead, rng)
    assert abs(est.theta - rate * 4.0) < math.radians(3.5)
