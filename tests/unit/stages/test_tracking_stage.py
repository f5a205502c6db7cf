"""The tracking stage: messages in and out, pairing features with their scans by stamp,
what it drops and counts, its launch parameters, and the process shell's build."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from agent.calibration.table import Calibration
from agent.errors import ConfigError
from agent.runtime import topics
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import (
    Features,
    FilteredScan,
    Header,
    Message,
    Odometry,
    Tracks,
    VehicleState,
    WheelCommand,
    decode,
    encode,
)
from agent.runtime.stage import Output, Params, Stage
from agent.sim.world_file import load_world
from agent.stages.calibration_stage import CalibrationStage
from agent.stages.features_stage import FeaturesStage
from agent.stages.filtering_stage import FilteringStage
from agent.stages.head_stage import HeadStage
from agent.stages.tracking_stage import WAITING_FEATURES, TrackingStage
from agent.stages.world_stage import WorldStage
from agent.tracking.tracker import KIND_CORNER, KIND_CYLINDER, KIND_SEGMENT, STATUS_TENTATIVE
from cli.bench_graph import vehicle_state_of
from processes import tracking as tracking_process
from tests.unit.tracking.scenes import Scene, cast, corner_walls, features

OFFICE = Path(__file__).resolve().parents[3] / "worlds" / "office.toml"
SCENE = Scene(walls=corner_walls((1.8, 0.3), math.pi), corners=np.array([[1.8, 0.3]]),
              pillars=np.array([[1.5, -0.4, 0.1]]))  # fmt: skip


def _state(stamp_ns: int, x: float = 0.0, cov: float = 1e-4) -> VehicleState:
    return VehicleState(
        header=Header(stamp_ns=stamp_ns, frame_id="odom"), x_m=x, y_m=0.0, yaw_rad=0.0,
        speed_m_s=0.0, yaw_rate_rad_s=0.0, pose_covariance=np.eye(3) * cov,
        intent_xy=np.zeros((0, 2)),
    )  # fmt: skip


def _scan_and_features(
    stamp_ns: int, rng: np.random.Generator, pose: np.ndarray | None = None
) -> tuple[FilteredScan, Features]:
    pose = np.zeros(3) if pose is None else pose
    scan, hits = cast(pose, SCENE, stamp_ns * 1e-9, 0.0, (-0.35, 0.35))
    batch, _ = features(pose, SCENE, stamp_ns * 1e-9, scan, hits, rng)
    n = scan.flag.size
    filtered = FilteredScan(
        header=Header(stamp_ns=stamp_ns, frame_id="base_link"),
        points_xy=scan.points_xy, covariance=np.full((n, 2, 2), np.nan),
        origin_xy=scan.origin_xy, scan_angle_rad=scan.scan_angle_rad,
        intensity_A=np.zeros(n), range_m=scan.range_m, sigma_m=np.full(n, 1e-3),
        flag=scan.flag, segment=np.zeros(n, dtype=np.int32), sweep_index=0,
        motion_compensated=True,
    )  # fmt: skip
    feats = Features(
        header=Header(stamp_ns=stamp_ns, frame_id="base_link"), kind=batch.kind,
        params=batch.params, covariance=batch.covariance, endpoints=batch.endpoints,
        nearer_side=np.zeros(batch.kind.size, dtype=np.int32),
        reflectivity=batch.reflectivity,
    )  # fmt: skip
    return filtered, feats


def _wire(msg: FilteredScan | Features | VehicleState) -> FilteredScan | Features | VehicleState:
    """Through the wire encoding, as the bus and the lock-step runner deliver it."""
    out = decode(encode(msg))
    assert isinstance(out, type(msg))
    return out


def _run(stage: TrackingStage, scans: int, seed: int = 1) -> list[Tracks]:
    rng = np.random.default_rng(seed)
    out: list[Tracks] = []
    for k in range(scans):
        stamp = 100_000_000 * (k + 1)
        stage.handle(topics.VEHICLE_STATE, _wire(_state(stamp - 5_000_000)), 0.0)
        scan, feats = _scan_and_features(stamp, rng)
        stage.handle(topics.FILTERED_SCAN, _wire(scan), 0.0)
        for topic, msg in stage.handle(topics.FEATURES, _wire(feats), 0.0):
            assert topic == topics.TRACKS and isinstance(msg, Tracks)
            out.append(msg)
    return out


def test_features_become_tracks_in_odom_stamped_with_the_scan() -> None:
    stage = TrackingStage()
    out = _run(stage, 6)
    assert len(out) == 6
    last = out[-1]
    assert last.header.frame_id == "odom" and last.header.stamp_ns == 600_000_000
    kinds = set(last.kind[last.status != STATUS_TENTATIVE].tolist())
    assert {KIND_CORNER, KIND_CYLINDER} <= kinds
    decoded = decode(encode(last))  # the message is valid on the wire
    assert isinstance(decoded, Tracks) and np.array_equal(decoded.track_id, last.track_id)
    c = stage.counters()
    assert c["tracks_published"] == 6 and c["features_without_scan"] == 0


def test_features_pair_with_the_scan_of_their_stamp() -> None:
    rng = np.random.default_rng(2)
    stage = TrackingStage()
    stage.handle(topics.VEHICLE_STATE, _state(0), 0.0)
    scan_a, feats_a = _scan_and_features(50_000_000, rng)
    scan_b, feats_b = _scan_and_features(150_000_000, rng)
    stage.handle(topics.FILTERED_SCAN, scan_a, 0.0)
    stage.handle(topics.FILTERED_SCAN, scan_b, 0.0)
    stage.handle(topics.VEHICLE_STATE, _state(160_000_000), 0.0)
    assert len(stage.handle(topics.FEATURES, feats_a, 0.0)) == 1  # its scan is held
    assert len(stage.handle(topics.FEATURES, feats_b, 0.0)) == 1
    # Features before their scan (two sockets, no order between them) wait for it ...
    scan_c, feats_c = _scan_and_features(250_000_000, rng)
    stage.handle(topics.VEHICLE_STATE, _state(260_000_000), 0.0)
    assert stage.handle(topics.FEATURES, feats_c, 0.0) == []
    [(topic, tracks)] = stage.handle(topics.FILTERED_SCAN, scan_c, 0.0)
    assert topic == topics.TRACKS and tracks.header.stamp_ns == 250_000_000
    assert stage.counters()["features_waited"] == 1
    # ... but not for ever: the oldest of more than WAITING_FEATURES waiting is dropped.
    for i in range(WAITING_FEATURES + 1):
        _, orphan = _scan_and_features(300_000_000 + i * 100_000_000, rng)
        assert stage.handle(topics.FEATURES, orphan, 0.0) == []
    assert stage.counters()["features_without_scan"] == 1


def test_features_without_a_pose_or_with_a_stale_one_are_dropped_and_counted() -> None:
    rng = np.random.default_rng(3)
    stage = TrackingStage()
    scan, feats = _scan_and_features(1_000_000_000, rng)
    stage.handle(topics.FILTERED_SCAN, scan, 0.0)
    assert stage.handle(topics.FEATURES, feats, 0.0) == []
    assert stage.counters()["features_no_vehicle_state"] == 1
    stage.handle(topics.VEHICLE_STATE, _state(500_000_000), 0.0)  # 0.5 s before the scan
    assert stage.handle(topics.FEATURES, feats, 0.0) == []
    assert stage.counters()["features_stale_pose"] == 1
    stage.handle(topics.VEHICLE_STATE, _state(990_000_000), 0.0)
    assert len(stage.handle(topics.FEATURES, feats, 0.0)) == 1
    # The same scan again: not later than the last used.
    assert stage.handle(topics.FEATURES, feats, 0.0) == []
    assert stage.counters()["features_out_of_order"] == 1


def test_bad_input_is_counted_and_dropped() -> None:
    rng = np.random.default_rng(4)
    stage = TrackingStage()
    stage.handle(topics.VEHICLE_STATE, _state(0), 0.0)
    bad_state = _state(10_000_000, cov=1e-4)
    bad_state.pose_covariance[0, 0] = np.nan
    stage.handle(topics.VEHICLE_STATE, bad_state, 0.0)
    stage.handle(topics.VEHICLE_STATE, _state(5_000_000), 0.0)
    stage.handle(topics.VEHICLE_STATE, _state(5_000_000), 0.0)
    scan, feats = _scan_and_features(50_000_000, rng)
    stage.handle(topics.FILTERED_SCAN, scan, 0.0)
    # One feature's covariance is broken: it alone is dropped.
    cov = feats.covariance.copy()
    cov[0, 0, 0] = -1.0
    broken = Features(header=feats.header, kind=feats.kind, params=feats.params,
                      covariance=cov, endpoints=feats.endpoints, nearer_side=feats.nearer_side,
                      reflectivity=feats.reflectivity)  # fmt: skip
    [(_, tracks)] = stage.handle(topics.FEATURES, broken, 0.0)
    assert isinstance(tracks, Tracks) and len(tracks.track_id) == feats.kind.size - 1
    wrong = Features(header=Header(stamp_ns=60_000_000, frame_id="odom"), kind=feats.kind,
                     params=feats.params, covariance=feats.covariance,
                     endpoints=feats.endpoints, nearer_side=feats.nearer_side,
                     reflectivity=feats.reflectivity)  # fmt: skip
    assert stage.handle(topics.FEATURES, wrong, 0.0) == []
    assert stage.handle(topics.HEAD_STATE, feats, 0.0) == []  # a message on the wrong topic
    c = stage.counters()
    assert c["vehicle_state_malformed"] == 1
    assert c["vehicle_state_duplicate"] == 1 and c["vehicle_state_out_of_order"] == 0
    assert c["features_malformed"] == 1 and c["features_wrong_frame"] == 1


def test_same_inputs_give_the_same_tracks() -> None:
    a = _run(TrackingStage(), 8, seed=9)
    b = _run(TrackingStage(), 8, seed=9)
    assert [encode(m) for m in a] == [encode(m) for m in b]


def test_launch_parameters() -> None:
    stage = tracking_process.build(
        Params("tracking", {"gate_probability": 0.995, "confirm_hits": 2, "max_state_age_s": 0.2})
    )
    assert isinstance(stage, TrackingStage)
    assert stage.tracker.settings.confirm_hits == 2 and stage.max_state_age_s == 0.2
    with pytest.raises(ConfigError, match="unknown parameter"):
        TrackingStage.from_params(Params("tracking", {"gate": 0.9}))
    with pytest.raises(ConfigError, match="gate_probability"):
        TrackingStage.from_params(Params("tracking", {"gate_probability": "high"}))
    with pytest.raises(ConfigError, match="process tracking: need 1 <= confirm_hits"):
        TrackingStage.from_params(Params("tracking", {"confirm_hits": 9}))


# ---------------------------------------------------------------- the real pipeline
class _OdometryToVehicleState(Stage):
    """The vehicle controller's part: its odometry as the agent's vehicle state."""

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if not isinstance(msg, Odometry):
            return []
        return [(topics.VEHICLE_STATE, vehicle_state_of(msg))]


def test_office_pipeline_keeps_static_ids_while_driving(calibration: Calibration) -> None:
    # World, head, calibration, filtering, features and tracking in lock-step on the office
    # world; the vehicle creeps forward turning slowly (0.1 m/s, 0.05 rad/s) for 10 s, its
    # odometry drifting; the crate's faces and corner, then the far wall, are tracked.
    world = load_world(OFFICE)
    tracking = TrackingStage()
    runner = LockstepRunner(
        [
            Node("world", WorldStage(world, rate_hz=50.0, seed=1), (topics.WHEEL_COMMAND,)),
            Node("vehicle", _OdometryToVehicleState(), (topics.ODOMETRY,)),
            Node("head", HeadStage(world, seed=1), (topics.HEAD_COMMAND, topics.WORLD_TRUTH)),
            Node("calibration", CalibrationStage(calibration), (topics.RAW_SCAN,)),
            Node("filtering", FilteringStage(calibration.noise_current_A),
                 (topics.CALIBRATED_SCAN, topics.VEHICLE_STATE)),
            Node("features",
                 FeaturesStage(calibration.signal_constant_Am2, calibration.noise_current_A),
                 (topics.FILTERED_SCAN,)),
            Node("tracking", tracking,
                 (topics.FEATURES, topics.FILTERED_SCAN, topics.VEHICLE_STATE)),
        ]
    )  # fmt: skip
    out: list[Tracks] = []
    runner.observe(lambda t, topic, msg: out.append(msg) if isinstance(msg, Tracks) else None,
                   topics.TRACKS)  # fmt: skip
    t = 0.0
    while t < 10.0:
        command = WheelCommand(header=Header(stamp_ns=round(t * 1e9)), speed_m_s=0.1,
                               yaw_rate_rad_s=0.05)  # fmt: skip
        runner.inject(topics.WHEEL_COMMAND, command)
        t += 0.25
        runner.run_until(t)
    assert len(out) >= 95  # a tracks message for (nearly) every scan
    confirmed = {int(i) for m in out for i in m.track_id[m.status != STATUS_TENTATIVE]}
    last = out[-1]
    assert len(confirmed) >= 3 and confirmed <= set(last.track_id.tolist()), "none deleted"
    # No id switch: no two confirmed tracks of one kind describe the same feature.
    keep = np.isin(last.track_id, list(confirmed))
    for kind in np.unique(last.kind[keep]):
        rows = np.flatnonzero(keep & (last.kind == kind))
        for a, b in itertools.combinations(rows, 2):
            if kind == KIND_SEGMENT:
                da = abs(math.remainder(last.params[a, 0] - last.params[b, 0], math.tau))
                assert da > 0.1 or abs(last.params[a, 1] - last.params[b, 1]) > 0.1
            else:
                assert np.hypot(*(last.state[a, :2] - last.state[b, :2])) > 0.3
    assert tracking.counters()["features_malformed"] == 0
