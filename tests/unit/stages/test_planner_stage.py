"""The planner stage: environment vectors, sensor health, head commands, and its free space
against the true world through the real simulator chain (lock-step)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from agent.calibration.table import Calibration
from agent.errors import ConfigError
from agent.kinematics.trajectory import ConstantTwist
from agent.planning.free_space import FreeSpaceMap
from agent.planning.policies import ForwardPolicy, HeadLimits, SweepPolicy
from agent.runtime import topics
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import (
    EnvironmentVector,
    FilteredScan,
    HeadCommand,
    Header,
    HeadState,
    Message,
    Tracks,
    VehicleState,
    WheelCommand,
    WorldTruth,
    decode,
    stamp_ns,
)
from agent.runtime.stage import Output, Params, Stage
from agent.sim.movers import mover_states
from agent.sim.raycast import cast_rays, ray_directions
from agent.sim.world import World, world_from_obstacles
from agent.sim.world_file import load_world
from agent.stages.calibration_stage import CalibrationStage
from agent.stages.filtering_stage import FilteringStage
from agent.stages.head_stage import HeadStage
from agent.stages.planner_stage import PlannerStage
from agent.stages.vehicle_stage import environment_view
from agent.stages.world_stage import WorldStage
from processes import planner as planner_process

REPO = Path(__file__).resolve().parents[3]
OFFICE = REPO / "worlds" / "office.toml"
MOUNT = 0.30


def _tracks(stamp_s: float, kind: list[int] | None = None, status: list[int] | None = None,
            reflectivity: list[float] | None = None) -> Tracks:  # fmt: skip
    kind = kind or []
    k = len(kind)
    z = np.zeros
    return Tracks(
        header=Header(stamp_ns=stamp_ns(stamp_s), frame_id="odom"),
        track_id=np.arange(k, dtype=np.int64), kind=np.array(kind, dtype=np.uint8),
        status=np.array(status or [1] * k, dtype=np.uint8), state=z((k, 4)),
        covariance=np.tile(np.eye(4), (k, 1, 1)), params=z((k, 3)),
        params_covariance=z((k, 3, 3)), extent=z((k, 4)), end_seen=z((k, 2), np.uint8),
        reflectivity=np.array(reflectivity or [1.0] * k), moving_probability=z(k),
        last_seen_ns=z(k, np.int64), hits=z(k, np.int64),
    )  # fmt: skip


def _vehicle(stamp_s: float, x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> VehicleState:
    return VehicleState(
        header=Header(stamp_ns=stamp_ns(stamp_s), frame_id="odom"), x_m=x, y_m=y, yaw_rad=yaw,
        speed_m_s=0.0, yaw_rate_rad_s=0.0, pose_covariance=np.eye(3) * 1e-6,
        intent_xy=np.zeros((0, 2)),
    )  # fmt: skip


def _head_state(
    stamp_s: float,
    mode: str = "scanning",
    pan: float = 0.0,
    target: float = 0.0,
    laser: bool = True,
    accepted: bool = True,
    sweeps: int = 0,
) -> HeadState:
    half = math.radians(20)
    return HeadState(
        header=Header(stamp_ns=stamp_ns(stamp_s), frame_id="base_link"), pan_rad=pan,
        pan_rate_rad_s=0.0, target_pan_rad=target, window_low_rad=-half, window_high_rad=half,
        laser_on=laser, mode=mode, command_seq=0, command_accepted=accepted,
        command_message="", sweeps=sweeps,
    )  # fmt: skip


def _scan(stamp_s: float) -> FilteredScan:
    """A scan that saw nothing usable (all low signal): fresh, but clears nothing."""
    n = 8
    return FilteredScan(
        header=Header(stamp_ns=stamp_ns(stamp_s), frame_id="base_link"),
        points_xy=np.full((n, 2), np.nan), covariance=np.full((n, 2, 2), np.nan),
        origin_xy=np.tile([MOUNT, 0.0], (n, 1)), scan_angle_rad=np.linspace(-0.3, 0.3, n),
        intensity_A=np.zeros(n), range_m=np.full(n, np.nan), sigma_m=np.full(n, np.nan),
        flag=np.full(n, 2, dtype=np.uint8), segment=np.full(n, -1, dtype=np.int32),
        sweep_index=0, motion_compensated=True,
    )  # fmt: skip


def _envs(outputs: list[Output]) -> list[EnvironmentVector]:
    return [m for t, m in outputs if t == topics.ENVIRONMENT and isinstance(m, EnvironmentVector)]


def _commands(outputs: list[Output]) -> list[HeadCommand]:
    return [m for t, m in outputs if t == topics.HEAD_COMMAND and isinstance(m, HeadCommand)]


def _fresh(stage: PlannerStage, t: float, head: HeadState | None = None) -> None:
    stage.handle(topics.VEHICLE_STATE, _vehicle(t), t)
    stage.handle(topics.HEAD_STATE, head or _head_state(t), t)
    stage.handle(topics.FILTERED_SCAN, _scan(t), t)


# ------------------------------------------------------------------------------------ params
def test_processes_build_is_the_stage_from_params() -> None:
    stage = planner_process.build(Params("planner", {"policy": "sweep", "sweep_step_deg": 30.0}))
    assert isinstance(stage, PlannerStage)
    assert isinstance(stage.policy, SweepPolicy)
    assert len(stage.policy.pans) == 7


@pytest.mark.parametrize(
    ("values", "match"),
    [
        ({"policy": "stare"}, r"^process planner: parameter 'policy' = 'stare' is not one of "
                              r"forward, sweep, active, greedy$"),
        ({"policy": 3}, "parameter 'policy' must be str"),
        ({"valid_for_s": -1.0}, r"'valid_for_s' = -1.0 outside"),
        ({"sweep_dwell_sweeps": 0}, "sweep_dwell_sweeps"),
        ({"sweep_step_deg": 0.5}, "sweep_step_deg"),
        ({"free_space_max_age_s": 0.0}, "free_space_max_age_s"),
        ({"stale_after": 0.3}, "unknown parameter"),
    ],
)  # fmt: skip
def test_bad_params_are_refused_in_one_line(values: dict[str, object], match: str) -> None:
    with pytest.raises(ConfigError, match=match) as err:
        PlannerStage.from_params(Params("planner", values))
    assert "\n" not in str(err.value)


# ------------------------------------------------------------------------ environment vector
def test_one_vector_per_tracks_message_stamped_with_the_tracks() -> None:
    stage = PlannerStage(ForwardPolicy())
    stage.start(0.0)
    _fresh(stage, 1.0)
    out = stage.handle(topics.TRACKS, _tracks(1.0, [0, 3, 1], [1, 2, 0], [9.0, 1.0, 1.0]), 1.02)
    (env,) = _envs(out)
    assert env.header.stamp_ns == stamp_ns(1.0)
    assert env.header.frame_id == "odom"
    assert env.sensor_ok
    assert env.valid_for_s == pytest.approx(0.3)
    assert env.obstacle_id.tolist() == [0, 1]  # the tentative track is no obstacle
    assert env.kind.tolist() == [4, 3]  # a segment of reflectivity 9 is a docking target
    assert env.free_bearing_rad.shape == env.free_range_m.shape == (360,)
    assert stage.counters()["docking_targets"] == 1
    assert isinstance(decode(env.to_wire()), EnvironmentVector)  # within its ranges


def test_each_obstacle_says_how_long_ago_a_scan_updated_it() -> None:
    stage = PlannerStage(ForwardPolicy())
    stage.start(0.0)
    _fresh(stage, 2.0)
    msg = _tracks(2.0, [3, 3], [1, 2], [1.0, 1.0])
    msg = dataclasses.replace(msg, last_seen_ns=np.array([stamp_ns(2.0), stamp_ns(0.5)]))
    (env,) = _envs(stage.handle(topics.TRACKS, msg, 2.02))
    np.testing.assert_allclose(env.seen_age_s, [0.0, 1.5], atol=1e-9)
    # Seen longer ago than the message's range holds (a tracker's stamps on another clock
    # than the vector's): held to its bound, 1e6 s.
    msg = dataclasses.replace(msg, last_seen_ns=np.array([stamp_ns(2.0), -(2 * 10**15)]))
    (env,) = _envs(stage.handle(topics.TRACKS, msg, 2.03))
    assert env.seen_age_s[1] == 1e6
    assert isinstance(decode(env.to_wire()), EnvironmentVector)


@pytest.mark.parametrize(
    ("head", "reason"),
    [
        (_head_state(1.0, mode="fault", laser=False), "head_fault"),
        (_head_state(1.0, mode="idle", laser=False), "laser_off"),
        (_head_state(1.0, mode="idle", laser=False, accepted=False), "command_refused"),
    ],
)
def test_a_head_fault_makes_the_vector_not_ok(head: HeadState, reason: str) -> None:
    stage = PlannerStage(ForwardPolicy())
    stage.start(0.0)
    _fresh(stage, 1.0, head)
    (env,) = _envs(stage.handle(topics.TRACKS, _tracks(1.0), 1.0))
    assert not env.sensor_ok
    assert stage.counters()[f"not_ok_{reason}"] == 1


@pytest.mark.parametrize("stale", ["vehicle", "scans", "head"])
def test_stale_inputs_make_the_vector_not_ok(stale: str) -> None:
    stage = PlannerStage(ForwardPolicy(), stale_after_s=0.3)
    stage.start(0.0)
    _fresh(stage, 1.0)
    t = 1.5  # everything but the stale input is refreshed
    if stale != "vehicle":
        stage.handle(topics.VEHICLE_STATE, _vehicle(t), t)
    if stale != "head":
        stage.handle(topics.HEAD_STATE, _head_state(t), t)
    if stale != "scans":
        stage.handle(topics.FILTERED_SCAN, _scan(t), t)
    (env,) = _envs(stage.handle(topics.TRACKS, _tracks(t), t))
    assert not env.sensor_ok
    assert stage.counters()[f"not_ok_stale_{stale}"] == 1
    if stale == "vehicle":  # no pose at the stamp: no free space either
        assert np.all(env.free_range_m == 0.0)


def test_with_no_input_at_all_it_still_publishes_not_ok_at_a_steady_rate() -> None:
    stage = PlannerStage(ForwardPolicy(), idle_period_s=0.1)
    runner = LockstepRunner([Node("planner", stage, ())])
    seen: list[tuple[float, Message]] = []
    runner.observe(lambda t, topic, m: seen.append((t, m)), topics.ENVIRONMENT)
    runner.run_until(2.05)
    times = [t for t, _ in seen]
    assert len(times) == 20
    np.testing.assert_allclose(np.diff(times), 0.1, atol=1e-9)
    for _, env in seen:
        assert isinstance(env, EnvironmentVector)
        assert not env.sensor_ok
        assert len(env.obstacle_id) == 0
        assert np.all(env.free_range_m == 0.0)


def test_idle_vectors_stop_while_tracks_come_and_resume_when_they_stop() -> None:
    stage = PlannerStage(ForwardPolicy(), idle_period_s=0.1, stale_after_s=0.3)
    stage.start(0.0)
    t = 0.0
    while t < 1.0:  # tracks at 10 Hz: every vector is a tracks' one
        t = round(t + 0.1, 9)
        _fresh(stage, t)
        assert len(_envs(stage.handle(topics.TRACKS, _tracks(t), t))) == 1
        assert _envs(stage.tick(t + 0.05)) == []
    assert _envs(stage.tick(t + 0.2)) == []  # not yet stale
    (env,) = _envs(stage.tick(t + 0.35))
    assert not env.sensor_ok


def test_wrong_messages_are_ignored() -> None:
    stage = PlannerStage(ForwardPolicy())
    stage.start(0.0)
    assert stage.handle(topics.TRACKS, _vehicle(1.0), 1.0) == []
    assert stage.counters()["tracks"] == 0


def _full_scan(stamp_s: float, n: int = 256) -> FilteredScan:
    """A full window's sweep (the mirror from −20° to +20°, ``n`` samples ending at
    ``stamp_s``) that saw nothing usable."""
    scan = _scan(stamp_s)
    return FilteredScan(
        header=scan.header, points_xy=np.full((n, 2), np.nan),
        covariance=np.full((n, 2, 2), np.nan), origin_xy=np.tile([MOUNT, 0.0], (n, 1)),
        scan_angle_rad=np.linspace(-math.radians(20), math.radians(20), n),
        intensity_A=np.zeros(n), range_m=np.full(n, np.nan), sigma_m=np.full(n, np.nan),
        flag=np.full(n, 2, dtype=np.uint8), segment=np.full(n, -1, dtype=np.int32),
        sweep_index=0, motion_compensated=True,
    )  # fmt: skip


@pytest.mark.parametrize(("pan_deg", "yaw_rate"), [(60.0, 0.0), (0.0, 0.0), (-80.0, 0.5)])
def test_a_scan_at_a_steady_pan_names_its_window(pan_deg: float, yaw_rate: float) -> None:
    """The head held still at the pan through the sweep: the vector with the scan's stamp
    names the outermost beams' bearings, pan + θ (less the vehicle's turn since each beam,
    as for a no-return), about (pan − 20°, pan + 20°); a vector of another stamp names none."""
    pan = math.radians(pan_deg)
    stage = PlannerStage(ForwardPolicy())
    stage.start(0.0)
    turning = dataclasses.replace(_vehicle(1.0), yaw_rate_rad_s=yaw_rate)
    stage.handle(topics.VEHICLE_STATE, turning, 1.0)
    for t in (0.85, 1.0):  # the head's reports: before the sweep began, and at its end
        stage.handle(topics.HEAD_STATE, _head_state(t, pan=pan, target=pan), t)
    stage.handle(topics.FILTERED_SCAN, _full_scan(1.0), 1.0)
    (env,) = _envs(stage.handle(topics.TRACKS, _tracks(1.0), 1.0))
    sweep_s = 255 / 2560  # from the first sample to the last
    np.testing.assert_allclose(
        env.scan_window_rad,
        [pan - math.radians(20) - yaw_rate * sweep_s, pan + math.radians(20)], atol=1e-12,
    )  # fmt: skip
    assert env.sensor_ok and stage.counters()["scan_window_given"] == 1
    # Nothing returned light (every sample at the noise level): dark to the far limit in
    # the window's sectors, 0 outside it.
    inside = (env.free_bearing_rad >= env.scan_window_rad[0]) & (
        env.free_bearing_rad <= env.scan_window_rad[1]
    )
    assert 39 <= np.count_nonzero(inside) <= 44  # 40° and the vehicle's turn
    np.testing.assert_array_equal(env.scan_dark_m, np.where(inside, 2.5, 0.0))
    decoded = decode(env.to_wire())
    assert isinstance(decoded, EnvironmentVector)
    np.testing.assert_array_equal(decoded.scan_window_rad, env.scan_window_rad)
    # The vehicle's controller sees it as sent.
    np.testing.assert_array_equal(environment_view(decoded).scan_window_rad, env.scan_window_rad)
    np.testing.assert_array_equal(environment_view(decoded).scan_dark_m, env.scan_dark_m)
    # The seen profiles come with every vector: at least as far as the aged ones.
    assert env.seen_range_m.shape == env.seen_far_m.shape == env.seen_end_hit.shape == (360,)
    assert (env.seen_range_m >= env.free_range_m).all()
    np.testing.assert_array_equal(environment_view(decoded).seen_range_m, env.seen_range_m)
    (later,) = _envs(stage.handle(topics.TRACKS, _tracks(1.05), 1.05))
    assert later.scan_window_rad.shape == (0,) and later.scan_dark_m.shape == (0,)
    assert stage.counters()["scan_window_given"] == 1


def test_a_scan_while_the_head_slews_names_no_window_from_an_older_filter() -> None:
    """The head's reports show it moving through the sweep and the filter does not tell the
    beams' directions (an older one): they are not known, and the vector names no window."""
    stage = PlannerStage(ForwardPolicy())
    stage.start(0.0)
    stage.handle(topics.VEHICLE_STATE, _vehicle(1.0), 1.0)
    stage.handle(topics.HEAD_STATE, _head_state(0.85, pan=0.3, target=1.0), 0.85)
    stage.handle(topics.HEAD_STATE, _head_state(1.0, pan=0.8, target=1.0), 1.0)
    stage.handle(topics.FILTERED_SCAN, _full_scan(1.0), 1.0)
    (env,) = _envs(stage.handle(topics.TRACKS, _tracks(1.0), 1.0))
    assert env.scan_window_rad.shape == (0,)
    assert stage.counters()["scans_pan_unknown"] == 1
    assert stage.counters()["scan_window_given"] == 0


def test_a_scan_while_the_head_slews_names_the_window_its_beams_swept() -> None:
    """The head slews from 0.3 to 0.8 rad through the sweep; the filter tells each beam's
    direction (the head's pan at the sample plus the mirror's angle): the vector names the
    outermost beams' bearings, its no-returns are vouched for as at a steady pan, and the
    scan's dark sectors are those the beams swept."""
    n = 256
    stage = PlannerStage(ForwardPolicy())
    stage.start(0.0)
    stage.handle(topics.VEHICLE_STATE, _vehicle(1.0), 1.0)
    stage.handle(topics.HEAD_STATE, _head_state(0.85, pan=0.3, target=1.0), 0.85)
    stage.handle(topics.HEAD_STATE, _head_state(1.0, pan=0.8, target=1.0), 1.0)
    scan = _full_scan(1.0, n)
    beams = np.linspace(0.3, 0.8, n) + scan.scan_angle_rad
    stage.handle(topics.FILTERED_SCAN, dataclasses.replace(scan, beam_rad=beams), 1.0)
    (env,) = _envs(stage.handle(topics.TRACKS, _tracks(1.0), 1.0))
    np.testing.assert_allclose(env.scan_window_rad, [beams.min(), beams.max()], atol=1e-12)
    counts = stage.counters()
    assert counts["scans_pan_unknown"] == 0 and counts["scan_window_given"] == 1
    assert counts["beams_vouched"] > 0
    inside = (env.free_bearing_rad >= beams.min()) & (env.free_bearing_rad <= beams.max())
    assert 67 <= np.count_nonzero(inside) <= 69  # 40° and the pan's 0.5 rad (28.6°)
    np.testing.assert_array_equal(env.scan_dark_m, np.where(inside, 2.5, 0.0))
    # Told beams that do not match the scan's samples are not used: the scan is malformed.
    stage.handle(topics.FILTERED_SCAN, dataclasses.replace(scan, beam_rad=beams[:-1]), 1.1)
    assert stage.counters()["filtered_scan_malformed"] == 1


# ---------------------------------------------------------------------------- head commands
def test_commands_only_when_the_target_changes_and_again_when_not_taken() -> None:
    stage = PlannerStage(ForwardPolicy(), resend_after_s=0.5)
    stage.start(0.0)
    (cmd,) = _commands(stage.tick(0.1))
    assert (cmd.pan_rad, cmd.laser) == (0.0, True)
    assert cmd.window_high_rad == pytest.approx(math.radians(20))
    # The head took it: nothing more, however long.
    for k in range(2, 30):
        t = k * 0.1
        assert _commands(stage.handle(topics.HEAD_STATE, _head_state(t), t)) == []
        assert _commands(stage.tick(t)) == []
    # The head shows another target (it restarted, say): sent again, not at once.
    assert _commands(stage.handle(topics.HEAD_STATE, _head_state(3.0, target=0.5), 3.0)) != []
    assert _commands(stage.handle(topics.HEAD_STATE, _head_state(3.1, target=0.5), 3.1)) == []
    assert stage.counters()["head_commands_resent"] == 1


def test_sweep_policy_drives_the_simulated_head_through_its_pans() -> None:
    world = load_world(OFFICE)
    stage = PlannerStage(SweepPolicy(math.radians(40), 1, HeadLimits()))
    head = HeadStage(world, seed=3)
    runner = LockstepRunner(
        [Node("head", head, (topics.HEAD_COMMAND,)), Node("planner", stage, (topics.HEAD_STATE,))]
    )
    commands: list[HeadCommand] = []
    states: list[HeadState] = []
    runner.observe(lambda t, topic, m: commands.append(m), topics.HEAD_COMMAND)  # type: ignore[arg-type]
    runner.observe(lambda t, topic, m: states.append(m), topics.HEAD_STATE)  # type: ignore[arg-type]
    runner.run_until(8.0)
    pans = [round(math.degrees(c.pan_rad)) for c in commands]
    assert pans[:10] == [0, 40, 80, 40, 0, -40, -80, -40, 0, 40]
    assert all(s.command_accepted for s in states)
    assert head.counters()["refused"] == 0
    assert stage.counters()["head_commands_resent"] == 0


# ----------------------------------------------------------------- free space vs the truth
class _Odometry(Stage):
    """Vehicle states from the world's truth (odometry = truth for this test)."""

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if not isinstance(msg, WorldTruth):
            return []
        state = VehicleState(
            header=Header(stamp_ns=msg.header.stamp_ns, frame_id="odom"), x_m=msg.x_m,
            y_m=msg.y_m, yaw_rad=msg.yaw_rad, speed_m_s=msg.speed_m_s,
            yaw_rate_rad_s=msg.yaw_rate_rad_s, pose_covariance=np.eye(3) * 1e-6,
            intent_xy=np.zeros((0, 2)),
        )  # fmt: skip
        return [(topics.VEHICLE_STATE, state)]


class _NoTracks(Stage):
    """Empty tracks with every filtered scan's stamp: one vector per scan."""

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if not isinstance(msg, FilteredScan):
            return []
        return [(topics.TRACKS, _tracks(msg.header.stamp_s))]


def _office_with_a_mover() -> World:
    """The office's static obstacles and a mover crossing 1.2 m ahead of the vehicle."""
    office = load_world(OFFICE)
    walls = [(o.points, o.reflectivity) for o in office.obstacles if o.kind == "wall"]
    boxes = [
        (o.center, o.size, o.yaw_rad, o.reflectivity) for o in office.obstacles if o.kind == "box"
    ]
    cylinders = [
        (o.center, o.radius, o.reflectivity) for o in office.obstacles if o.kind == "cylinder"
    ]
    mover = (np.array([[1.2, 0.6], [1.0, -1.6]]), 0.2, 0.8, 0.9)  # path, radius, speed, ρ
    return world_from_obstacles(walls, boxes, cylinders, office.vehicle_pose, "office+", [mover])


def _run(world: World, calibration: Calibration, policy: str, seed: int, duration_s: float):  # type: ignore[no-untyped-def]
    stage = PlannerStage.from_params(Params("planner", {"policy": policy}))
    runner = LockstepRunner([
        Node("world", WorldStage(world, rate_hz=20.0), (topics.WHEEL_COMMAND,)),
        Node("odometry", _Odometry(), (topics.WORLD_TRUTH,)),
        Node("head", HeadStage(world, seed=seed), (topics.HEAD_COMMAND, topics.WORLD_TRUTH)),
        Node("calibration", CalibrationStage(calibration), (topics.RAW_SCAN,)),
        Node("filtering", FilteringStage(calibration.noise_current_A),
             (topics.CALIBRATED_SCAN, topics.VEHICLE_STATE)),
        Node("tracking", _NoTracks(), (topics.FILTERED_SCAN,)),
        Node("planner", stage, (topics.TRACKS, topics.FILTERED_SCAN, topics.VEHICLE_STATE,
                                topics.HEAD_STATE)),
    ])  # fmt: skip
    truths: list[WorldTruth] = []
    envs: list[EnvironmentVector] = []
    runner.observe(lambda t, topic, m: truths.append(m), topics.WORLD_TRUTH)  # type: ignore[arg-type]
    runner.observe(lambda t, topic, m: envs.append(m), topics.ENVIRONMENT)  # type: ignore[arg-type]
    rng = np.random.default_rng(seed)
    t = 0.0
    while t < duration_s:  # drive about: forward up to 0.3 m/s, turning either way
        speed, turn = rng.uniform(0.0, 0.3), rng.uniform(-0.6, 0.6)
        runner.inject(topics.WHEEL_COMMAND, WheelCommand(header=Header(), speed_m_s=speed,
                                                         yaw_rate_rad_s=turn))  # fmt: skip
        t = round(t + 0.5, 9)
        runner.run_until(t)
    return stage, truths, envs


def _collides(centres: np.ndarray, radii: list[float], pose: tuple[float, float, float]) -> bool:
    """Does any mover overlap the vehicle's 0.8 m × 0.6 m body at ``pose``?"""
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    for (mx, my), r in zip(centres, radii, strict=True):
        bx, by = c * (mx - x) + s * (my - y), -s * (mx - x) + c * (my - y)
        if math.hypot(max(abs(bx) - 0.4, 0.0), max(abs(by) - 0.3, 0.0)) < r:
            return True
    return False


def _false_free(
    world: World, truths: list[WorldTruth], envs: list[EnvironmentVector]
) -> tuple[int, int]:
    """(bearings claimed, of them claimed clear beyond a true surface), from the true pose."""
    static = world_from_obstacles(
        [(o.points, o.reflectivity) for o in world.obstacles if o.kind == "wall"],
        [(o.center, o.size, o.yaw_rad, o.reflectivity) for o in world.obstacles if o.kind == "box"],
        [(o.center, o.radius, o.reflectivity) for o in world.obstacles if o.kind == "cylinder"],
    )
    claimed = false = 0
    for env in envs:
        if not env.sensor_ok:
            continue
        ts = env.header.stamp_s
        tr = max((m for m in truths if m.header.stamp_s <= ts), key=lambda m: m.header.stamp_s)
        x, y, yaw = (float(v) for v in ConstantTwist(
            tr.x_m, tr.y_m, tr.yaw_rad, tr.speed_m_s, tr.yaw_rate_rad_s, tr.header.stamp_s
        ).poses_at(ts))  # fmt: skip
        claims = env.free_range_m > 0
        if not claims.any():
            continue
        centre = np.array([x + MOUNT * math.cos(yaw), y + MOUNT * math.sin(yaw)])
        rays = ray_directions(env.free_bearing_rad[claims] + yaw)
        truth = cast_rays(static, centre, rays).distance_m
        if world.movers:  # the movers where they are at the stamp
            xy, _ = mover_states(list(world.movers), ts)
            if _collides(xy, [m.radius_m for m in world.movers], (x, y, yaw)):
                continue  # a mover inside the vehicle: every ray starts in it (see the test)
            now = world_from_obstacles(
                cylinders=[(c, m.radius_m, 1.0) for c, m in zip(xy, world.movers, strict=True)]
            )
            truth = np.minimum(truth, cast_rays(now, centre, rays).distance_m)
        claimed += int(claims.sum())
        false += int(np.count_nonzero(env.free_range_m[claims] > truth))
    return claimed, false


@pytest.mark.parametrize(
    ("policy", "seed"), [("forward", 1), ("sweep", 2), ("forward", 3), ("sweep", 4)]
)
def test_free_space_is_never_claimed_beyond_a_true_obstacle(
    calibration: Calibration, policy: str, seed: int
) -> None:
    """The real chain (head, calibration, filtering) in the office with a mover crossing at
    0.8 m/s, the vehicle driving about; every claimed bearing is ray-cast in the true world
    from the true pose. Target: no false claim at all (the benchmark's bound is 0.1 %; over
    these ~3,000 claims a single one would be 0.03 %, so zero is the test that can fail).

    Vectors while the mover overlaps the vehicle's body (movers walk blindly, through the
    vehicle) are left out: the profile takes the body as free, and every ray then starts
    inside the mover. The world stops the vehicle for good at the contact (a collision): in
    seeds 1, 3 and 4 the mover runs into it (seed 1 at 4.2 s), so those runs claim less, at
    least 800 bearings."""
    world = _office_with_a_mover()
    stage, truths, envs = _run(world, calibration, policy, seed, 6.0)
    claimed, false = _false_free(world, truths, envs)
    assert stage.counters()["scans_added"] >= 50
    # Every vector names the window its scan's beams swept: 40°, give or take the vehicle's
    # turn over a sweep (0.6 rad/s commanded for 0.1 s: 3.4°; measured up to 3.5° with the
    # world's dynamics) and, for a scan taken while the head slewed (the sweep's pans), the
    # pan's travel over the sweep (at most 180°/s for 0.1 s: 18°).
    windows = np.array([e.scan_window_rad for e in envs if e.scan_window_rad.size])
    assert len(windows) >= 50, len(windows)
    widths = np.degrees(windows[:, 1] - windows[:, 0])
    assert (np.abs(widths - 40.0) <= 4.0 + (18.0 if policy == "sweep" else 0.0)).all(), widths
    assert claimed >= 800, claimed  # it does claim free space
    assert false == 0, (false, claimed)


def test_the_map_is_the_domain_class() -> None:
    assert isinstance(PlannerStage(ForwardPolicy()).free_space, FreeSpaceMap)


def test_the_active_planner_says_which_obstacles_it_maintains() -> None:
    from agent.planning.active import ActivePolicy

    for policy, expected in ((ForwardPolicy(), 0), (ActivePolicy(), 2)):
        stage = PlannerStage(policy)
        stage.start(0.0)
        _fresh(stage, 1.0)
        out = stage.handle(topics.TRACKS, _tracks(1.0, [0, 3, 1], [1, 2, 0], [9.0, 1.0, 1.0]), 1.02)
        (env,) = _envs(out)
        # The passive policy says nothing; the active one one flag per obstacle.
        assert env.maintained.shape == (expected,)
        assert set(env.maintained.tolist()) <= {0, 1}
        assert isinstance(decode(env.to_wire()), EnvironmentVector)


def test_the_active_planners_command_says_why() -> None:
    from agent.planning.active import ActivePolicy, Decision
    from agent.planning.policies import HeadTarget
    from agent.runtime.messages import HeadCommand

    stage = PlannerStage(ActivePolicy())
    stage.start(0.0)
    _fresh(stage, 1.0)  # the head settled at pan 0 (sweep 0): the next sweep decides
    stage.handle(topics.HEAD_STATE, _head_state(1.1, sweeps=1), 1.1)
    assert stage.policy.decision is not None  # type: ignore[attr-defined]
    target = HeadTarget(0.5, -0.2, 0.1)
    stage.policy.decision = Decision(target, 7.0, 1.5, 0.45, 1.1)  # type: ignore[attr-defined]
    _, cmd = stage._command(target, 1.2)
    assert isinstance(cmd, HeadCommand)
    assert (cmd.utility_bits, cmd.cost_s) == (pytest.approx(8.5), pytest.approx(0.45))
    # Another target than the decision's, or a reward not in bits, says no utility.
    _, other = stage._command(HeadTarget(0.0, -0.2, 0.2), 1.3)
    assert isinstance(other, HeadCommand) and (other.utility_bits, other.cost_s) == (0.0, 0.0)
    stage.policy.decision = Decision(target, 0.0, 3.0, 0.45, 1.1, in_bits=False)  # type: ignore[attr-defined]
    _, greedy = stage._command(target, 1.4)
    assert isinstance(greedy, HeadCommand)
    assert (greedy.utility_bits, greedy.cost_s) == (0.0, pytest.approx(0.45))
    # A passive policy's commands weigh nothing.
    passive = PlannerStage(ForwardPolicy())
    passive.start(0.0)
    (cmd,) = [m for _, m in passive.tick(0.1) if isinstance(m, HeadCommand)]
    assert cmd.utility_bits == 0.0 and cmd.cost_s == 0.0
