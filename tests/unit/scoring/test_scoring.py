"""Tests of the scoring functions on hand-computed cases (no simulation)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from agent.scoring.frames import PoseHistory, line_params, to_frame, world_to_odom
from agent.scoring.free_space import FreeSpaceScore, score_profile, true_clear_range
from agent.scoring.gospa import assign, gospa
from agent.scoring.identity import IdentityLedger
from agent.scoring.nees import average_interval, nees
from agent.scoring.tracking import ScanInput, TrackingScore, TrackView
from agent.scoring.truth import circles_hit, corners_hit, scene_truth
from agent.sim.world import World

C = 0.5


# ------------------------------------------------------------------------------- GOSPA
def test_gospa_hand_computed_parts() -> None:
    # Truth at (0,0), (1,0), (5,5); estimates at (0.1,0) [0.1 away], (1,0.3) [0.3 away],
    # (3,3) [far from all]. p = 1: localisation 0.1 + 0.3 = 0.4; one missed, one false,
    # each c/2 = 0.25; total 0.9.
    g = gospa([[0, 0], [1, 0], [5, 5]], [[0.1, 0], [1, 0.3], [3, 3]], c=C, p=1)
    assert g.localisation == pytest.approx(0.4)
    assert g.missed == pytest.approx(0.25)
    assert g.false == pytest.approx(0.25)
    assert g.distance == pytest.approx(0.9)
    assert sorted(map(tuple, g.pairs.tolist())) == [(0, 0), (1, 1)]


def test_gospa_empty_sets() -> None:
    assert gospa(np.zeros((0, 2)), np.zeros((0, 2))).distance == 0.0
    g = gospa([[0, 0], [1, 1]], np.zeros((0, 2)), c=C)
    assert (g.missed, g.false, g.distance) == (pytest.approx(0.5), 0.0, pytest.approx(0.5))
    g = gospa(np.zeros((0, 2)), [[0, 0]], c=C)
    assert (g.missed, g.false, g.distance) == (0.0, pytest.approx(0.25), pytest.approx(0.25))


def test_gospa_pair_at_cutoff_is_split() -> None:
    # At exactly c (or beyond) a pair costs as much as a miss and a false: left unassigned.
    g = gospa([[0, 0]], [[0.5, 0]], c=C)
    assert g.pairs.shape == (0, 2)
    assert g.distance == pytest.approx(0.5)
    g = gospa([[0, 0]], [[0.49, 0]], c=C)
    assert g.localisation == pytest.approx(0.49)


def test_gospa_optimal_not_greedy() -> None:
    # Greedy would pair truth 0 with estimate 0 (0.1) and leave truth 1 at 0.45 from
    # estimate 1... here the optimum is the crossing-free one: total 0.2 + 0.2 < 0.1 + 0.45.
    truth = [[0.0, 0.0], [0.3, 0.0]]
    est = [[0.2, 0.0], [-0.2, 0.0]]  # greedy: t0-e0 is 0.2, t0-e1 0.2, t1-e0 0.1, t1-e1 0.5
    g = gospa(truth, est, c=C)
    # Options: (t0-e1 0.2, t1-e0 0.1) = 0.3; (t0-e0 0.2, t1-e1 0.5 -> split, 0.5) = 0.7.
    assert g.distance == pytest.approx(0.3)


def test_gospa_p2_and_kinds() -> None:
    # p = 2: localisation 0.3² = 0.09, and c²/2 = 0.125 for the estimate of another kind
    # plus 0.125 for the truth it could not take: total sqrt(0.34).
    g = gospa(
        [[0, 0], [2, 0]], [[0.3, 0], [2, 0.01]], c=C, p=2,
        truth_kind=[1, 1], estimate_kind=[1, 3],
    )  # fmt: skip
    assert g.localisation == pytest.approx(0.09)
    assert g.missed == pytest.approx(0.125)
    assert g.false == pytest.approx(0.125)
    assert g.distance == pytest.approx(math.sqrt(0.34))
    with pytest.raises(ValueError):
        gospa([[0, 0]], [[0, 0]], alpha=1.0)
    with pytest.raises(ValueError):
        assign([[0, 0]], [[0, 0]], c=0.0)


# ------------------------------------------------------------------------------ frames
def test_world_to_odom_is_where_a_perfect_tracker_puts_it() -> None:
    # Truth: vehicle at (1, 0) facing +y; odometry believes (1.1, 0.05) facing +y + 0.1 rad.
    # A point 1 m ahead of the vehicle (world (1, 1)) is 1 m ahead of the odometry's pose.
    true_pose = np.array([1.0, 0.0, math.pi / 2])
    odom_pose = np.array([1.1, 0.05, math.pi / 2 + 0.1])
    got = world_to_odom(true_pose, odom_pose, np.array([[1.0, 1.0]]))[0]
    expected = np.array([1.1 + math.cos(math.pi / 2 + 0.1), 0.05 + math.sin(math.pi / 2 + 0.1)])
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # With no drift it is the identity.
    pts = np.array([[3.0, -2.0], [0.5, 0.25]])
    np.testing.assert_allclose(world_to_odom(true_pose, true_pose, pts), pts, atol=1e-12)
    np.testing.assert_allclose(to_frame([1, 2, math.pi], [[1.0, 0.0]]), [[0.0, 2.0]], atol=1e-12)


def test_line_params_and_pose_history() -> None:
    # The line y = 2 (from (0,2) to (1,2)): normal +y, α = π/2, ρ = 2.
    np.testing.assert_allclose(line_params(np.array([[0.0, 2.0]]), np.array([[1.0, 2.0]])),
                               [[math.pi / 2, 2.0]], atol=1e-12)  # fmt: skip
    h = PoseHistory()
    assert h.at(0.0) is None
    h.add(0.0, 0.0, 0.0, math.pi - 0.1)
    h.add(1.0, 1.0, 2.0, -math.pi + 0.1)  # crosses ±π: interpolates through π
    pose = h.at(0.5)
    assert pose is not None
    np.testing.assert_allclose(pose, [0.5, 1.0, math.pi], atol=1e-12)
    assert h.at(1.5) is None


# -------------------------------------------------------------------------------- NEES
def test_nees_hand_computed() -> None:
    e = np.array([[1.0, 2.0], [0.0, 0.0], [1.0, 0.0]])
    P = np.array([np.diag([1.0, 4.0]), np.eye(2), np.zeros((2, 2))])
    got = nees(e, P)
    assert got[0] == pytest.approx(1.0 + 1.0)
    assert got[1] == 0.0
    assert math.isnan(got[2])  # singular: no NEES
    lo, hi = average_interval(2, 100)
    assert (lo, hi) == (pytest.approx(1.63, abs=0.01), pytest.approx(2.41, abs=0.01))
    lo, hi = average_interval(4, 100)
    assert (lo, hi) == (pytest.approx(3.47, abs=0.01), pytest.approx(4.57, abs=0.01))


def test_nees_is_chi2_for_consistent_errors() -> None:
    # 20 000 draws from N(0, P): the mean NEES is 3 within 0.06 (5 σ of the mean is
    # 5·sqrt(2·3/20000) = 0.087; a tighter 0.06 still passes with this seed at 3.4 σ).
    rng = np.random.default_rng(7)
    A = rng.normal(size=(3, 3))
    P = A @ A.T + np.eye(3)
    e = rng.multivariate_normal(np.zeros(3), P, size=20000)
    assert float(nees(e, np.broadcast_to(P, (20000, 3, 3))).mean()) == pytest.approx(3.0, abs=0.06)


# ---------------------------------------------------------------------------- identity
def test_identity_switches_and_fragmentations() -> None:
    ledger = IdentityLedger()
    ledger.update([(1, 100), (2, 200)], [1, 2])  # first tracks: nothing
    ledger.update([(1, 100)], [1, 2])  # 200 unassigned for a scan: nothing
    ledger.update([(1, 100), (2, 200)], [1, 2])  # re-associated with its own track
    assert (ledger.id_switches, ledger.fragmentations) == (0, 0)
    ledger.update([(3, 200)], [1, 3])  # track 2 deleted, 200 now tracked by 3
    assert (ledger.id_switches, ledger.fragmentations) == (0, 1)
    ledger.update([(4, 100)], [1, 3, 4])  # track 1 alive, 100 taken over by 4: a switch
    assert (ledger.id_switches, ledger.fragmentations) == (1, 1)
    ledger.update([(3, 100)], [1, 3, 4])  # track 3 moves from 200 to 100: a switch
    assert (ledger.id_switches, ledger.fragmentations) == (2, 1)


# ------------------------------------------------------------------------------- truth
def _box_world() -> World:
    # A 1 m × 0.5 m box at (2, 0), a cylinder r 0.2 at (0, 2), an open wall with one bend
    # of 90° at (4, 1) and one of 5° at (4, 3).
    return World.build(
        walls=[(((4.0, -1.0), (4.0, 1.0), (5.0, 1.0)), 1.0),
               (((4.0, 2.0), (4.0, 3.0), (4.0 + math.sin(0.087), 4.0)), 1.0)],
        boxes=[((2.0, 0.0), (1.0, 0.5), 0.0, 1.0)],
        cylinders=[((0.0, 2.0), 0.2, 1.0)],
    )  # fmt: skip


def test_scene_truth_corners() -> None:
    truth = scene_truth(_box_world())
    corners = {tuple(np.round(c, 6)) for c in truth.corner_xy.tolist()}
    assert corners == {(1.5, -0.25), (2.5, -0.25), (2.5, 0.25), (1.5, 0.25), (4.0, 1.0)}
    np.testing.assert_allclose(truth.cylinder_xy, [[0.0, 2.0]])


def test_hits() -> None:
    truth = scene_truth(_box_world())
    # Samples on the box's near face (x = 1.5) and bottom face (y = -0.25) close to their
    # corner (1.5, -0.25): 5 on each hits that corner only.
    face1 = np.stack([np.full(5, 1.5), np.linspace(-0.2, -0.05, 5)], axis=1)
    face2 = np.stack([np.linspace(1.55, 1.75, 5), np.full(5, -0.25)], axis=1)
    sigma = np.full(10, 0.002)
    hit = corners_hit(truth, np.concatenate([face1, face2]), sigma)
    corner = np.flatnonzero(np.all(np.isclose(truth.corner_xy, [1.5, -0.25]), axis=1))
    assert hit.sum() == 1 and hit[corner[0]]
    assert not corners_hit(truth, face1, sigma[:5]).any()  # one face only
    # Seen from (1.5, -3), the face x = 1.5 is grazed (beams about 89° from its normal): no
    # corner; from (0, -1.5) both faces are seen within 60° of their normals.
    both = np.concatenate([face1, face2])
    assert not corners_hit(truth, both, sigma, np.array([1.45, -3.0]))[corner[0]]
    assert corners_hit(truth, both, sigma, np.array([0.0, -1.5]))[corner[0]]
    # Five samples on the cylinder's outline (4 cm off with σ 2 cm: within 3σ) hit it.
    angles = np.linspace(-2.0, -1.0, 5)
    ring = np.array([0.0, 2.0]) + 0.24 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    assert circles_hit(truth.cylinder_xy, truth.cylinder_radius_m, ring, np.full(5, 0.02))[0]
    assert not circles_hit(truth.cylinder_xy, truth.cylinder_radius_m, ring, np.full(5, 0.002))[0]
    assert circles_hit(truth.cylinder_xy, truth.cylinder_radius_m, ring, np.full(5, 0.002), 0.02)[0]


# -------------------------------------------------------------------------- free space
def test_free_space_claims_against_truth() -> None:
    # A wall across x = 2 (world); the vehicle at the origin facing +x, its centre of
    # scanning at (0.3, 0): truly clear 1.7 m straight ahead; a mover of radius 0.2 at
    # (1.3, 1.0) blocks the bearing toward it at 1.0·√2 - 0.2 from the centre of scanning.
    world = World.build(walls=[(((2.0, -5.0), (2.0, 5.0)), 1.0)])
    mover = np.array([[1.3, 1.0]])
    radius = np.array([0.2])
    bearings = np.array([0.0, math.pi / 4, math.pi])
    truth = true_clear_range(world, mover, radius, np.array([0.3, 0.0]), bearings)
    assert truth[0] == pytest.approx(1.7)
    assert truth[1] == pytest.approx(math.sqrt(2.0) - 0.2)
    assert truth[2] == math.inf
    score = FreeSpaceScore()
    # Claims: 1.705 ahead (within 1 cm: fine), 1.3 toward the mover (false), 0 behind.
    score_profile(score, world, mover, radius, [0, 0, 0], bearings, [1.705, 1.3, 0.0])
    assert (score.claimed, score.false, score.false_at_mover) == (2, 1, 1)
    assert score.false_free_rate == pytest.approx(0.5)
    # Coverage: (1.705 + 1.3 + 0) / (1.7 + 1.2142 + 2.5).
    assert score.coverage == pytest.approx(3.005 / (1.7 + math.sqrt(2.0) - 0.2 + 2.5))


def test_free_space_profile_in_collision_is_counted_not_scored() -> None:
    # A mover of radius 0.2 at (0.55, 0.25): 0.15 m past the 0.8 x 0.6 footprint's front
    # edge and inside its width, so it overlaps the vehicle; one at (0.65, 0.25) does not.
    world = World.build(walls=[(((2.0, -5.0), (2.0, 5.0)), 1.0)])
    bearings = np.array([0.0, math.pi / 4])
    score = FreeSpaceScore()
    score_profile(score, world, [[0.55, 0.25]], [0.2], [0, 0, 0], bearings, [1.7, 1.7])
    assert (score.in_collision, score.profiles, score.claimed) == (1, 0, 0)
    score_profile(score, world, [[0.65, 0.25]], [0.2], [0, 0, 0], bearings, [1.7, 1.7])
    assert (score.in_collision, score.profiles, score.claimed) == (1, 1, 2)


# ------------------------------------------------------------------- the scan accumulator
def _scan(stamp: float, drift: float = 0.0, points: np.ndarray | None = None) -> ScanInput:
    return ScanInput(
        stamp_s=stamp,
        true_pose=np.array([0.0, 0.0, 0.0]),
        odom_pose=np.array([drift, 0.0, 0.0]),
        points_base=np.zeros((0, 2)) if points is None else points,
        sigma_m=np.zeros(0) if points is None else np.full(points.shape[0], 0.002),
        origin_base=np.array([0.3, 0.0]),
        mover_xy=np.zeros((0, 2)),
        mover_velocity_xy=np.zeros((0, 2)),
        mover_radius_m=np.zeros(0),
    )


def _cylinder_track(track_id: int, xy: tuple[float, float], sd: float = 0.05) -> TrackView:
    cov = np.diag([sd**2, sd**2, 1e-4, 1e-4])[None]
    return TrackView(
        track_id=np.array([track_id]), kind=np.array([3], dtype=np.uint8),
        confirmed=np.array([True]), state=np.array([[xy[0], xy[1], 0.0, 0.0]]),
        covariance=cov, params=np.full((1, 3), np.nan),
        params_covariance=np.full((1, 3, 3), np.nan), extent=np.zeros((1, 4)),
        moving_probability=np.zeros(1),
    )  # fmt: skip


def test_tracking_score_drift_and_known() -> None:
    # One cylinder r 0.2 at (1.5, 0) in the world; odometry 0.1 m ahead of the truth along
    # x, so a perfect tracker puts it at (1.6, 0) in odom.
    world = World.build(cylinders=[((1.5, 0.0), 0.2, 1.0)])
    score = TrackingScore(min_hits=1)
    score.start_run(scene_truth(world), 0)
    angles = np.linspace(2.8, 3.5, 6)
    ring = np.array([1.5, 0.0]) + 0.2 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    # Scan 1: no samples, the cylinder is not known yet; the track paired with it is left
    # out of GOSPA (neither false nor localised).
    score.add_scan(_scan(0.0, 0.1), _cylinder_track(7, (1.6, 0.05)))
    # Scan 2: its samples hit the cylinder: known; the track 0.05 m off: localisation 0.05.
    score.add_scan(_scan(0.1, 0.1, ring), _cylinder_track(7, (1.6, 0.05)))
    # Scan 3: the track is gone: missed, c/2.
    score.add_scan(_scan(0.2, 0.1), _cylinder_track(8, (9.0, 9.0)))
    s = score.summary()
    assert s["gospa"]["localisation"] == pytest.approx(0.05 / 3)
    assert s["gospa"]["missed"] == pytest.approx(0.25 / 3)
    assert s["gospa"]["false"] == 0.0  # the track at (9, 9) is out of reach
    assert s["false_tracks_per_scan"] == pytest.approx(1 / 3)  # ... but it is false
    assert s["position_rmse_m"]["cylinder"] == pytest.approx(0.05)
    # NEES of (0, 0.05) against σ 0.05 m: 1, in both scans that paired.
    assert s["nees"]["static"]["mean"] == pytest.approx(1.0)
    assert s["nees"]["static"]["runs"] == 1
    assert s["static_deleted_out_of_view"] + s["static_deleted_in_view"] == 1


def test_nees_is_split_by_update_and_its_bulk_from_its_tail() -> None:
    # A pillar's track 0.05 m off in y: σ 0.05 (NEES 1) updated on two scans, σ 0.025
    # (NEES 4) coasting on one, and σ 0.005 (NEES 100, beyond χ²(2) 99.9 %, 13.8) updated
    # on one. Mean of the run 26.5; within 99.9 %, 2.0; one sample in four beyond it.
    world = World.build(cylinders=[((1.5, 0.0), 0.2, 1.0)])
    score = TrackingScore(min_hits=1)
    score.start_run(scene_truth(world), 0)
    for i, (sd, updated) in enumerate(((0.05, True), (0.05, True), (0.025, False), (0.005, True))):
        track = dataclasses.replace(
            _cylinder_track(1, (1.5, 0.05), sd), updated=np.array([updated])
        )
        score.add_scan(_scan(0.1 * i), track)
    block = score.summary()["nees"]["static"]
    assert block["mean"] == pytest.approx(26.5)
    assert block["updated"] == {
        "samples": 3,
        "mean": pytest.approx(34.0),
        "median": pytest.approx(1.0),
    }
    assert block["coasting"] == {
        "samples": 1,
        "mean": pytest.approx(4.0),
        "median": pytest.approx(4.0),
    }
    assert block["within_999"]["mean"] == pytest.approx(2.0)
    assert block["within_999"]["beyond_share"] == pytest.approx(0.25)


def test_known_after_min_hits_scans() -> None:
    # With the default 3 hits, the cylinder becomes known (and missed when untracked) only
    # at the third scan whose samples hit it.
    world = World.build(cylinders=[((1.5, 0.0), 0.2, 1.0)])
    score = TrackingScore()
    score.start_run(scene_truth(world), 0)
    angles = np.linspace(2.8, 3.5, 6)
    ring = np.array([1.5, 0.0]) + 0.2 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    nothing = _cylinder_track(1, (9.0, 9.0))
    for i in range(4):
        score.add_scan(_scan(0.1 * i, 0.0, ring), nothing)
    # Scans 3 and 4 miss it: 2 × c/2 over 4 scans.
    assert score.summary()["gospa"]["missed"] == pytest.approx(2 * 0.25 / 4)


def test_a_track_keeps_its_object_while_within_c() -> None:
    # Two pillars 0.3 m apart; a track starts on the first, then drifts to 0.1 m from the
    # second (0.2 m from its own): it stays the first's (CLEAR MOT), no switch, error 0.2.
    world = World.build(cylinders=[((1.5, 0.0), 0.05, 1.0), ((1.5, 0.3), 0.05, 1.0)])
    score = TrackingScore(min_hits=1)
    score.start_run(scene_truth(world), 0)
    score.add_scan(_scan(0.0), _cylinder_track(1, (1.5, 0.0)))
    score.add_scan(_scan(0.1), _cylinder_track(1, (1.5, 0.2)))
    s = score.summary()
    assert s["id_switches"] == 0
    assert s["position_rmse_m"]["cylinder"] == pytest.approx(math.sqrt(0.2**2 / 2))


def test_a_track_switches_object_only_when_updated() -> None:
    # Two pillars 0.45 m apart; a tight track of the first drifts, coasting, to 0.6 m from
    # it and 0.15 m from the second (beyond c and its own gate): it took no feature, so it
    # still follows the first (no switch; its error, 0.6 m, is charged to it). Updated
    # there, it has taken the second's: a switch.
    world = World.build(cylinders=[((1.5, 0.0), 0.05, 1.0), ((1.5, 0.45), 0.05, 1.0)])
    for updated, switches, rmse in ((False, 0, math.sqrt(0.6**2 / 2)), (True, 1, 0.15 / 2**0.5)):
        score = TrackingScore(min_hits=1)
        score.start_run(scene_truth(world), 0)
        score.add_scan(_scan(0.0), _cylinder_track(1, (1.5, 0.0), 0.01))
        view = dataclasses.replace(
            _cylinder_track(1, (1.5, 0.6), 0.01), updated=np.array([updated])
        )
        score.add_scan(_scan(0.1), view)
        s = score.summary()
        assert s["id_switches"] == switches, updated
        assert s["position_rmse_m"]["cylinder"] == pytest.approx(rmse), updated


def test_an_updated_track_on_the_object_takes_it_from_a_coasting_one() -> None:
    # Track 1 on a pillar, then coasting 0.8 m off while a new track 2 takes the pillar's
    # features: the pillar is track 2's now (an id switch: another id took it over while
    # track 1 lives), and track 1, unpaired, charges no 0.8 m error.
    world = World.build(cylinders=[((1.5, 0.0), 0.05, 1.0)])
    score = TrackingScore(min_hits=1)
    score.start_run(scene_truth(world), 0)
    score.add_scan(_scan(0.0), _cylinder_track(1, (1.5, 0.0), 0.01))
    one = _cylinder_track(1, (1.5, 0.8), 0.01)
    two = _cylinder_track(2, (1.5, 0.01), 0.01)
    both = TrackView(
        **{
            f.name: np.concatenate([getattr(one, f.name), getattr(two, f.name)])
            for f in dataclasses.fields(TrackView)
            if f.name not in ("updated", "information_bits")
        },
        updated=np.array([False, True]),
    )
    score.add_scan(_scan(0.1), both)
    s = score.summary()
    assert (s["id_switches"], s["fragmentations"]) == (1, 0)
    assert s["position_rmse_m"]["cylinder"] == pytest.approx(0.01 / 2**0.5)


def _segment_track(track_id: int, x: float, sd_rho: float) -> TrackView:
    # A segment along y from (x, -0.5) to (x, 0.5): α = 0, ρ = x.
    pcov = np.diag([1e-4, sd_rho**2, np.nan])
    return TrackView(
        track_id=np.array([track_id]), kind=np.array([0], dtype=np.uint8),
        confirmed=np.array([True]), state=np.array([[x, 0.0, 0.0, 0.0]]),
        covariance=np.diag([sd_rho**2, 0.25, 1e-4, 1e-4])[None],
        params=np.array([[0.0, x, np.nan]]), params_covariance=pcov[None],
        extent=np.array([[x, -0.5, x, 0.5]]), moving_probability=np.zeros(1),
    )  # fmt: skip


def test_a_drifted_track_inside_its_own_gate_is_not_false() -> None:
    # A pillar at (1.5, 0) and a wall along x = 2: tracks 0.7 m off (beyond c = 0.5). With
    # σ 0.3 m the object is inside the track's 99 % gate (d² = 5.4 < 9.21): not false, but
    # beyond c; with σ 0.05 m it is false either way.
    world = World.build(
        cylinders=[((1.5, 0.0), 0.2, 1.0)], walls=[(((2.0, -1.0), (2.0, 1.0)), 1.0)]
    )
    for sd, false in ((0.3, 0), (0.05, 1)):
        for view in (_cylinder_track(1, (1.5, 0.7), sd), _segment_track(2, 2.7, sd)):
            score = TrackingScore(min_hits=1)
            score.start_run(scene_truth(world), 0)
            score.add_scan(_scan(0.0), view)
            s = score.summary()
            assert s["false_tracks_per_scan"] == false, (sd, view.kind)
            assert s["false_tracks_beyond_c_per_scan"] == 1


def test_a_static_track_deleted_out_of_view_whose_place_comes_back_is_counted() -> None:
    # A pillar track at (1.5, 0); the scan then looks left (its wedge about +90°), the track
    # is deleted there: out of view; the next scan looks ahead again: its place came back.
    world = World.build(cylinders=[((1.5, 0.0), 0.2, 1.0)])
    score = TrackingScore(min_hits=1)
    score.start_run(scene_truth(world), 0)
    ahead = np.array([[1.8, -0.2], [1.8, 0.2]])
    left = np.array([[0.1, 1.5], [0.5, 1.5]])
    gone = _cylinder_track(9, (9.0, 9.0))
    score.add_scan(_scan(0.0, 0.0, ahead), _cylinder_track(1, (1.5, 0.0)))
    score.add_scan(_scan(0.1, 0.0, left), gone)
    assert score.static_deleted_out_of_view == 1
    assert score.static_deleted_out_of_view_returned == 0
    score.add_scan(_scan(0.2, 0.0, ahead), gone)
    assert score.summary()["static_deleted_out_of_view_returned"] == 1


def test_path_figures_count_from_entering_the_paths_reach_and_weigh_its_objects() -> None:
    # A pillar on the path ahead and one 3 m off it; a mover whose surface comes within
    # 2.5 m of the path at 0.1 s and is confirmed at 0.5 s.
    world = World.build(
        cylinders=[((1.5, 0.0), 0.2, 1.0), ((1.5, 3.0), 0.2, 1.0)],
    )
    score = TrackingScore(min_hits=1)
    score.start_run(scene_truth(world), 1)
    path = np.array([[0.5, 0.0], [1.5, 0.0], [2.5, 0.0]])
    angles = np.linspace(2.8, 3.5, 6)
    ring = np.array([1.5, 0.0]) + 0.2 * np.stack([np.cos(angles), np.sin(angles)], axis=1)

    def scan(t: float, mover_y: float) -> ScanInput:
        return dataclasses.replace(
            _scan(t, 0.0, ring), mover_xy=np.array([[2.0, mover_y]]),
            mover_velocity_xy=np.array([[0.0, -1.0]]), mover_radius_m=np.array([0.2]),
            path_ahead_xy=path,
        )  # fmt: skip

    pillar = _cylinder_track(1, (1.5, 0.0), sd=0.02)
    for i, y in enumerate([3.0, 2.6, 2.5, 2.4, 2.3]):  # surface within 2.5 m from 0.1 s on
        score.add_scan(scan(0.1 * i, y), pillar)
    both = TrackView.points(
        np.array([1, 2]), np.array([3, 3], dtype=np.uint8),
        np.array([[1.5, 0.0, 0.0, 0.0], [2.0, 2.2, 0.0, -1.0]]),
        np.array([np.diag([0.02**2, 0.02**2, 1e-4, 1e-4])] * 2),
    )  # fmt: skip
    score.add_scan(scan(0.5, 2.2), both)
    path_figures = score.summary()["path"]
    assert path_figures["confirm_latency_s"]["p50"] == pytest.approx(0.4)
    assert path_figures["confirm_latency_s"]["entries"] == 1
    # The pillar on the path is relevant (σ 0.02 m), the one 3 m off is not.
    assert path_figures["track_sigma_m_mean"] == pytest.approx(0.02)
    assert path_figures["objects_tracked"] == 1.0


def test_information_counts_the_bits_gained_per_second_and_those_near_the_path() -> None:
    # Two tracks, new at the first scan: a pillar on the path, a wall 3 m off it. Over
    # 0.2 s the pillar's updates tell 1 + 2 bits and the wall's 4: 35 bit/s in all, 15 near
    # the path.
    world = World.build(cylinders=[((1.5, 0.0), 0.2, 1.0)])
    score = TrackingScore(min_hits=1)
    score.start_run(scene_truth(world), 0)
    path = np.array([[0.5, 0.0], [1.5, 0.0], [2.5, 0.0]])
    pillar, wall = _cylinder_track(1, (1.5, 0.0)), _segment_track(2, 1.0, 0.01)
    wall = dataclasses.replace(wall, extent=np.array([[1.0, 3.0, 2.0, 3.0]]))

    def both(pillar_bits: float, wall_bits: float) -> TrackView:
        return TrackView(
            **{
                f.name: np.concatenate([getattr(pillar, f.name), getattr(wall, f.name)])
                for f in dataclasses.fields(TrackView)
                if f.name not in ("updated", "information_bits")
            },
            information_bits=np.array([pillar_bits, wall_bits]),
        )

    for t, bits in ((0.0, (0.0, 0.0)), (0.1, (1.0, 4.0)), (0.2, (3.0, 4.0))):
        score.add_scan(dataclasses.replace(_scan(t), path_ahead_xy=path), both(*bits))
    info = score.summary()["information"]
    assert info["seconds"] == pytest.approx(0.2)
    assert info["bits_per_s"] == pytest.approx((1.0 + 2.0 + 4.0) / 0.2)
    assert info["path_bits_per_s"] == pytest.approx(3.0 / 0.2)


def test_information_is_not_reported_for_tracks_that_do_not_carry_it() -> None:
    world = World.build(cylinders=[((1.5, 0.0), 0.2, 1.0)])
    score = TrackingScore(min_hits=1)
    score.start_run(scene_truth(world), 0)
    for t in (0.0, 0.1):
        score.add_scan(_scan(t), _cylinder_track(1, (1.5, 0.0)))
    assert score.summary()["information"]["bits_per_s"] is None
