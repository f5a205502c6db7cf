"""The world stage with motion: movers in world_truth, drifting odometry beside it, and the
vehicle's speed, yaw-rate and acceleration limits."""

from __future__ import annotations

import itertools
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.arrays import FloatArray
from agent.errors import ConfigError
from agent.kinematics.vehicle import VehicleSpec
from agent.runtime import topics
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import Header, Message, Odometry, WheelCommand, WorldTruth, decode
from agent.runtime.stage import Output, Params
from agent.sim.movers import mover_states
from agent.sim.odometry import OdometryErrorModel
from agent.sim.world import World
from agent.sim.world_file import load_world
from agent.stages.head_stage import HeadStage
from agent.stages.world_stage import WorldStage, _Piece

REPO = Path(__file__).resolve().parents[3]
CROSSING = REPO / "worlds" / "crossing.toml"
OPEN = World.build(walls=[(((-50.0, 50.0), (50.0, 50.0)), 1.0)])  # one far wall


def _by_topic(outputs: list[Output], topic: str) -> list[Message]:
    return [msg for t, msg in outputs if t == topic]


def _drive(stage: WorldStage, until_s: float) -> list[tuple[Odometry, WorldTruth]]:
    """Tick the stage up to ``until_s``; every tick gives odometry, then world truth."""
    out = []
    while (due := stage.next_tick_s()) is not None and due <= until_s + 1e-9:
        outputs = stage.tick(due)
        assert [t for t, _ in outputs] == [topics.ODOMETRY, topics.WORLD_TRUTH]
        odometry, truth = (msg for _, msg in outputs)
        assert isinstance(odometry, Odometry) and isinstance(truth, WorldTruth)
        out.append((odometry, truth))
    return out


def _wheel(speed: float, yaw_rate: float) -> WheelCommand:
    return WheelCommand(header=Header(), speed_m_s=speed, yaw_rate_rad_s=yaw_rate)


def test_world_truth_carries_the_movers_at_the_stamp() -> None:
    world = load_world(CROSSING)
    stage = WorldStage(world, rate_hz=20.0)
    stage.start(100.0)
    for _, truth in _drive(stage, 101.0):
        t = truth.header.stamp_s
        xy, vxy = mover_states(world.movers, t)
        np.testing.assert_allclose(truth.mover_xy, xy, atol=1e-9)
        np.testing.assert_allclose(truth.mover_velocity_xy, vxy)
        np.testing.assert_array_equal(truth.mover_radius_m, [0.2, 0.15])
        # Through the wire and back.
        back = decode(truth.to_wire())
        assert isinstance(back, WorldTruth)
        np.testing.assert_array_equal(back.mover_xy, truth.mover_xy)


def test_a_world_without_movers_has_empty_mover_arrays() -> None:
    stage = WorldStage(load_world(REPO / "worlds" / "box_before_wall.toml"))
    stage.start(0.0)
    _, truth = _drive(stage, 0.0)[0]
    assert truth.mover_xy.shape == (0, 2) and truth.mover_radius_m.shape == (0,)


def test_odometry_starts_at_the_start_pose_and_drifts_while_driving() -> None:
    world = OPEN  # nothing to run into over the 8 m drive
    stage = WorldStage(world, rate_hz=20.0, command_timeout_s=100.0, seed=7)
    stage.start(0.0)
    first, truth0 = _drive(stage, 0.0)[0]
    assert (first.x_m, first.y_m, first.yaw_rad) == world.vehicle_pose
    assert first.header.frame_id == "odom" and truth0.header.frame_id == "world"
    np.testing.assert_array_equal(first.pose_covariance, np.zeros((3, 3)))
    assert first.distance_m == 0.0 and first.speed_m_s == 0.0
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.4, 0.1), 0.0)
    pairs = _drive(stage, 20.0)
    odometry, truth = pairs[-1]
    # 8 m driven (less 0.16 m lost speeding up): the odometry is off by centimetres to
    # decimetres, and its covariance says so.
    assert odometry.distance_m == pytest.approx(8.0 - 0.16, rel=0.05)
    error = np.array([truth.x_m - odometry.x_m, truth.y_m - odometry.y_m])
    assert 1e-4 < float(np.hypot(*error)) < 1.0
    sigma = np.sqrt(np.diag(odometry.pose_covariance))
    assert np.all(sigma > 0.0) and sigma[0] < 1.0 and sigma[2] < 0.5
    variances = [np.trace(o.pose_covariance[:2, :2]) for o, _ in pairs[::20]]
    assert all(b > a for a, b in itertools.pairwise(variances))
    # Measured velocity, over the last second: about the commanded one. Per 0.05 s tick each
    # wheel's slip is sigma = sqrt(1e-5 m * 0.02 m) = 0.45 mm, so the yaw rate read over one
    # tick scatters by 0.025 rad/s (0.0057 averaged over 20 ticks); the drawn ratio error
    # adds 0.03 rad/m * 0.4 m/s = 0.012 rad/s (1 sigma): 0.04 rad/s is 3 sigma of both.
    # Speed: scale error 1.5 % (0.006 m/s) and slip 0.0014 m/s averaged: 0.02 is > 3 sigma.
    last = pairs[-20:]
    assert np.mean([o.speed_m_s for o, _ in last]) == pytest.approx(0.4, abs=0.02)
    assert np.mean([o.yaw_rate_rad_s for o, _ in last]) == pytest.approx(0.1, abs=0.04)
    back = decode(odometry.to_wire())
    assert isinstance(back, Odometry)
    np.testing.assert_array_equal(back.pose_covariance, odometry.pose_covariance)


def _final_odometry(seed: int) -> tuple[float, float, float]:
    stage = WorldStage(OPEN, rate_hz=20.0, command_timeout_s=100.0, seed=seed)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.3, -0.2), 0.0)
    odometry, _ = _drive(stage, 5.0)[-1]
    return odometry.x_m, odometry.y_m, odometry.yaw_rad


def test_odometry_is_seeded() -> None:
    assert _final_odometry(3) == _final_odometry(3)
    assert _final_odometry(3) != _final_odometry(4)


def test_from_params_reads_the_odometry_model() -> None:
    params = Params(
        "world",
        {"world": str(CROSSING), "seed": 5, "wheel_track_m": 0.45, "wheel_scale_sigma": 0.01,
         "wheel_ratio_sigma": 0.02, "wheel_track_sigma": 0.03, "wheel_slip_m": 2e-5},
    )  # fmt: skip
    stage = WorldStage.from_params(params)
    assert stage.odometry.model == OdometryErrorModel(0.45, 0.01, 0.02, 0.03, 2e-5)
    default = WorldStage.from_params(Params("world", {"world": str(CROSSING)}))
    assert default.odometry.model == OdometryErrorModel()
    with pytest.raises(ConfigError, match="wheel_slip_m"):
        WorldStage.from_params(Params("world", {"world": str(CROSSING), "wheel_slip_m": 1.0}))
    with pytest.raises(ConfigError, match="seed"):
        WorldStage.from_params(Params("world", {"world": str(CROSSING), "seed": 1.5}))
    with pytest.raises(ConfigError, match="unknown parameter"):
        WorldStage.from_params(Params("world", {"world": str(CROSSING), "odometry": 1}))


def test_lockstep_world_and_head_see_the_same_movers() -> None:
    # The world publishes odometry and truth; the head's sweeps see the movers where the
    # world says they are (both read the graph clock, no message between them about it).
    world = load_world(CROSSING)
    runner = LockstepRunner(
        [
            Node("world", WorldStage(world, rate_hz=20.0), (topics.WHEEL_COMMAND,)),
            Node("head", HeadStage(world, seed=1), (topics.HEAD_COMMAND, topics.WORLD_TRUTH)),
        ]
    )
    seen: list[tuple[float, str, Message]] = []
    runner.observe(lambda t, topic, msg: seen.append((t, topic, msg)))
    runner.run_until(0.5)
    odometry = [m for _, t, m in seen if t == topics.ODOMETRY]
    truths = [m for _, t, m in seen if t == topics.WORLD_TRUTH]
    assert len(odometry) == len(truths) >= 10
    assert all(isinstance(m, Odometry) and m.header.source == "world" for m in odometry)
    assert all(isinstance(m, WorldTruth) and m.mover_xy.shape == (2, 2) for m in truths)
    head = runner.nodes[1].stage
    assert isinstance(head, HeadStage) and head.sweeps >= 4
    assert math.isclose(head.simulator.world.movers[0].speed_m_s, 0.4)


# --------------------------------------------------------------------------------------------
# Limits: the vehicle's speed, yaw rate and accelerations
# --------------------------------------------------------------------------------------------
START = (1.0, -0.5, 0.3)
EXACT_ODOMETRY = OdometryErrorModel(scale_sigma=0.0, ratio_sigma=0.0, track_sigma=0.0, slip_m=0.0)


def _open_stage(**kwargs: Any) -> WorldStage:
    world = World.build(walls=[(((-50.0, 50.0), (50.0, 50.0)), 1.0)], vehicle_pose=START)
    return WorldStage(world, **kwargs)


def _reference(
    commands: list[tuple[float, float, float]],
    until_s: float,
    spec: VehicleSpec,
    timeout_s: float,
    initial: tuple[float, float] = (0.0, 0.0),
) -> tuple[FloatArray, FloatArray]:
    """The same drive by brute force: 200 000 midpoint steps of the rate-limited unicycle from
    START at ``initial`` speed and yaw rate. Returns times (k,) and states (k, 5): x, y, yaw,
    speed, yaw rate."""
    n = 200_000
    dt = until_s / n
    state = np.array([*START, *initial])
    out = [state.copy()]
    times = np.arange(n + 1) * dt
    for t in times[:-1]:
        live = [(v, w) for t_c, v, w in commands if t_c <= t < t_c + timeout_s]
        v_cmd, w_cmd = live[-1] if live else (0.0, 0.0)
        # Midpoint in time: speed first moves half a step, then the pose, then the rest.
        dv = np.clip(v_cmd - state[3], -spec.max_accel_m_s2 * dt, spec.max_accel_m_s2 * dt)
        dw = np.clip(
            w_cmd - state[4], -spec.max_yaw_accel_rad_s2 * dt, spec.max_yaw_accel_rad_s2 * dt
        )
        v, w = state[3] + 0.5 * dv, state[4] + 0.5 * dw
        yaw_mid = state[2] + 0.5 * w * dt
        state[0] += v * dt * math.cos(yaw_mid)
        state[1] += v * dt * math.sin(yaw_mid)
        state[2] += w * dt
        state[3] += dv
        state[4] += dw
        out.append(state.copy())
    return times.astype(np.float64), np.array(out, dtype=np.float64)


def test_speed_and_yaw_rate_ramp_at_the_vehicles_limits() -> None:
    spec = VehicleSpec()
    stage = _open_stage(rate_hz=20.0, command_timeout_s=10.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.5, 0.0), 0.0)
    truths = [truth for _, truth in _drive(stage, 2.0)]
    for truth in truths:
        t = truth.header.stamp_s
        # v = a·t up to 0.5 m/s (at 1 s); distance a·t²/2, then 0.25 m + 0.5·(t - 1).
        assert truth.speed_m_s == pytest.approx(min(spec.max_accel_m_s2 * t, 0.5), abs=1e-12)
        travelled = 0.25 * t * t if t <= 1.0 else 0.25 + 0.5 * (t - 1.0)
        assert math.hypot(truth.x_m - START[0], truth.y_m - START[1]) == pytest.approx(
            travelled, abs=1e-12
        )
        assert truth.yaw_rad == START[2]
    # Yaw rate: 2 rad/s² up to 1.5 rad/s, reached at 0.75 s.
    stage = _open_stage(rate_hz=20.0, command_timeout_s=10.0)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.0, 1.5), 0.0)
    for _, truth in _drive(stage, 1.5):
        t = truth.header.stamp_s
        assert truth.yaw_rate_rad_s == pytest.approx(min(2.0 * t, 1.5), abs=1e-12)
        turned = t * t if t <= 0.75 else 0.5625 + 1.5 * (t - 0.75)
        assert math.remainder(truth.yaw_rad - START[2] - turned, math.tau) == pytest.approx(
            0.0, abs=1e-12
        )
        assert (truth.x_m, truth.y_m) == START[:2]


def test_a_drive_with_ramps_matches_a_brute_force_integration() -> None:
    """Speed and yaw rate ramp together, change direction, and the command times out (the
    vehicle brakes): poses within 0.1 mm of 200 000 midpoint steps (which start each
    command up to one 2e-5 s step late: at under 1 m/s, micrometres)."""
    spec = VehicleSpec()
    commands = [(0.0, 0.45, 0.9), (0.61, -0.2, -1.5), (1.87, 0.5, 0.3)]
    stage = _open_stage(rate_hz=10.0, command_timeout_s=0.5)
    stage.start(0.0)
    truths: list[WorldTruth] = []
    for t_c, v, w in commands:
        truths += [truth for _, truth in _drive(stage, t_c - 1e-9)]
        stage.handle(topics.WHEEL_COMMAND, _wheel(v, w), t_c)
    truths += [truth for _, truth in _drive(stage, 4.0)]
    times, states = _reference(commands, 4.0, spec, 0.5)
    for truth in truths:
        i = round(truth.header.stamp_s / times[1])
        x, y, yaw, v, w = states[i]
        assert truth.x_m == pytest.approx(x, abs=1e-4)
        assert truth.y_m == pytest.approx(y, abs=1e-4)
        assert math.remainder(truth.yaw_rad - yaw, math.tau) == pytest.approx(0.0, abs=1e-4)
        assert truth.speed_m_s == pytest.approx(v, abs=1e-4)
        assert truth.yaw_rate_rad_s == pytest.approx(w, abs=1e-4)
    assert truths[-1].speed_m_s == 0.0 and truths[-1].yaw_rate_rad_s == 0.0  # braked, stopped
    assert max(math.dist((t.x_m, t.y_m), START[:2]) for t in truths) > 0.15  # it did drive


def test_odometry_without_errors_follows_the_true_motion_through_ramps() -> None:
    stage = _open_stage(rate_hz=20.0, command_timeout_s=0.7, odometry=EXACT_ODOMETRY)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.4, -1.0), 0.0)
    pairs = _drive(stage, 1.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(-0.3, 0.6), 1.0)
    pairs += _drive(stage, 3.0)
    for odometry, truth in pairs:
        assert odometry.x_m == pytest.approx(truth.x_m, abs=1e-9)
        assert odometry.y_m == pytest.approx(truth.y_m, abs=1e-9)
        assert math.remainder(odometry.yaw_rad - truth.yaw_rad, math.tau) == pytest.approx(
            0.0, abs=1e-9
        )


def test_limits_come_from_the_vehicle_and_the_old_names_still_work() -> None:
    spec = VehicleSpec(max_speed_m_s=0.3, max_yaw_rate_rad_s=1.0, max_accel_m_s2=1.0)
    stage = _open_stage(rate_hz=20.0, vehicle=spec)
    assert (stage.max_speed, stage.max_yaw_rate, stage.max_accel) == (0.3, 1.0, 1.0)
    assert stage.max_yaw_accel == spec.max_yaw_accel_rad_s2
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.5, -2.0), 0.0)
    assert (stage.command_speed, stage.command_yaw_rate) == (0.3, -1.0)
    assert stage.counters() == {"wheel_commands": 1, "clamped": 1}
    stage.tick(0.1)
    assert stage.speed == pytest.approx(0.1) and stage.yaw_rate == pytest.approx(-0.2)
    # The old keyword names override the vehicle's; inf accelerations change at once.
    stage = _open_stage(max_speed_m_s=0.2, max_accel_m_s2=math.inf, vehicle=spec)
    stage.start(0.0)
    stage.handle(topics.WHEEL_COMMAND, _wheel(0.5, 0.5), 0.0)
    assert (stage.speed, stage.command_speed, stage.yaw_rate) == (0.2, 0.2, 0.0)
    stage = _open_stage(max_speed_m_s=0.5, max_yaw_rate_rad_s=1.5)  # as before: still works
    assert (stage.max_speed, stage.max_yaw_rate, stage.max_accel) == (0.5, 1.5, 0.5)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"max_speed_m_s": -1.0}, "max_speed_m_s must be finite and >= 0"),
        ({"max_yaw_rate_rad_s": math.inf}, "max_yaw_rate_rad_s must be finite"),
        ({"max_accel_m_s2": 0.0}, "max_accel_m_s2 must be > 0"),
        ({"max_yaw_accel_rad_s2": math.nan}, "max_yaw_accel_rad_s2 must be > 0"),
        ({"rate_hz": 0.0}, "rate_hz and command_timeout_s must be positive"),
    ],
)
def test_bad_limits_are_refused(kwargs: dict[str, float], fragment: str) -> None:
    with pytest.raises(ValueError, match=re.escape(fragment)):
        _open_stage(**kwargs)


def test_from_params_reads_the_acceleration_limits() -> None:
    params = Params(
        "world", {"world": str(CROSSING), "max_accel_m_s2": 1.0, "max_yaw_accel_rad_s2": 3.0}
    )
    stage = WorldStage.from_params(params)
    assert (stage.max_accel, stage.max_yaw_accel) == (1.0, 3.0)
    default = WorldStage.from_params(Params("world", {"world": str(CROSSING)}))
    assert (default.max_speed, default.max_accel) == (0.5, 0.5)
    with pytest.raises(ConfigError, match="max_accel_m_s2"):
        WorldStage.from_params(Params("world", {"world": str(CROSSING), "max_accel_m_s2": 0}))


def test_poses_between_ticks_follow_the_ramp() -> None:
    """The poses the collision test sees inside a step: speed ramping through zero while the
    yaw rate ramps, against 200 000 midpoint steps; within 20 µm and 10 µrad (they agree to
    1e-13 here; a step's arc walked at a uniform pace instead would be 0.15 mm off)."""
    spec = VehicleSpec()
    # Speed 0.1 m/s ramping down through 0 at 0.2 s, yaw rate -0.4 rad/s ramping up to 0.6.
    piece = _Piece(START, 0.1, -0.4, -spec.max_accel_m_s2, spec.max_yaw_accel_rad_s2, 0.5)
    times, states = _reference([(0.0, -0.2, 0.6)], 0.5, spec, 10.0, initial=(0.1, -0.4))
    tau = np.linspace(0.0, 0.5, 101)
    poses = piece.poses(tau)
    expected = states[np.rint(tau / times[1]).astype(int)]
    np.testing.assert_allclose(poses[:, :2], expected[:, :2], atol=2e-5)
    np.testing.assert_allclose(poses[:, 2], expected[:, 2], atol=1e-5)
    np.testing.assert_allclose(poses[-1], piece.nodes[-1], atol=1e-12)


class _NumpyPiece:
    """The numpy formulation of a piece of motion, which the compiled one
    (:mod:`agent.stages.world_motion_kernels`) computes in the same order of operations."""

    def __init__(self, start: tuple[float, float, float], v0: float, w0: float, av: float,
                 aw: float, duration: float, n: int) -> None:  # fmt: skip
        self.times = duration * np.arange(n + 1) / n
        h = np.diff(self.times)
        mid = self.times[:-1] + 0.5 * h
        self.speed, self.yaw_rate = v0 + av * mid, w0 + aw * mid
        self.v0, self.w0, self.av, self.aw = v0, w0, av, aw
        yaw = start[2] + np.concatenate([[0.0], np.cumsum(self.yaw_rate * h)])
        dx, dy = self.arc(self.speed, self.yaw_rate, yaw[:-1], h)
        x = start[0] + np.concatenate([[0.0], np.cumsum(dx)])
        y = start[1] + np.concatenate([[0.0], np.cumsum(dy)])
        self.nodes = np.stack([x, y, yaw], axis=-1)

    @staticmethod
    def arc(speed: Any, yaw_rate: Any, yaw: Any, dt: Any) -> tuple[FloatArray, FloatArray]:
        turn = yaw_rate * dt
        chord = speed * dt * np.sinc(turn / (2.0 * math.pi))
        heading = yaw + 0.5 * turn
        return chord * np.cos(heading), chord * np.sin(heading)

    def poses(self, tau: FloatArray) -> FloatArray:
        i = np.clip(np.searchsorted(self.times, tau, side="right") - 1, 0, self.speed.size - 1)
        start, dt = self.times[i], tau - self.times[i]
        h = self.times[i + 1] - start
        v, w = self.speed[i], self.yaw_rate[i]
        if self.av != 0.0 or self.aw != 0.0:
            v_start, w_start = self.v0 + self.av * start, self.w0 + self.aw * start
            share = dt / h
            for rate_start, accel, mean in ((w_start, self.aw, w), (v_start, self.av, v)):
                rate_end = rate_start + accel * h
                steady = (rate_start * rate_end >= 0.0) & (mean != 0.0)
                done = (rate_start * dt + 0.5 * accel * dt * dt) / np.where(steady, mean * h, 1.0)
                share = np.where(steady, done, share)
            dt = h * np.clip(share, 0.0, 1.0)
        dx, dy = self.arc(v, w, self.nodes[i, 2], dt)
        node = self.nodes[i]
        return np.stack([node[:, 0] + dx, node[:, 1] + dy, node[:, 2] + self.yaw_rate[i] * dt], -1)

    def arcs(self, until: float) -> list[tuple[float, float]]:
        h = np.minimum(np.diff(self.times), np.maximum(until - self.times[:-1], 0.0))
        keep = h > 0.0
        return list(
            zip((self.speed * h)[keep].tolist(), (self.yaw_rate * h)[keep].tolist(), strict=True)
        )


@pytest.mark.parametrize("seed", range(3))
def test_the_compiled_motion_equals_its_numpy_formulation(seed: int) -> None:
    """Nodes, poses within and arcs of pieces that hold, ramp, turn on the spot or ramp
    through zero, equal to the bit (the truth, hence an evaluation's records, must not
    depend on which ran)."""
    rng = np.random.default_rng(seed)
    spec = VehicleSpec()
    for k in range(200):
        start = (*rng.uniform(-20.0, 20.0, 2).tolist(), float(rng.uniform(-7.0, 7.0)))
        v0, w0 = float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-1.5, 1.5))
        av = float(rng.choice([0.0, spec.max_accel_m_s2, -spec.max_accel_m_s2]))
        aw = float(rng.choice([0.0, spec.max_yaw_accel_rad_s2, -spec.max_yaw_accel_rad_s2]))
        if k % 7 == 0:
            v0 = 0.0  # turning on the spot
        if k % 11 == 0:
            w0 = 0.0  # straight
        duration = float(rng.uniform(0.001, 0.6))
        piece = _Piece(start, v0, w0, av, aw, duration)
        ref = _NumpyPiece(start, v0, w0, av, aw, duration, piece.speed.size)
        for name in ("times", "speed", "yaw_rate", "nodes"):
            np.testing.assert_array_equal(getattr(piece, name), getattr(ref, name), name)
        assert piece.end == tuple(ref.nodes[-1].tolist())
        tau = np.concatenate([rng.uniform(0.0, duration, 20), piece.times, [duration]])
        np.testing.assert_array_equal(piece.poses(tau), ref.poses(tau))
        for until in (*rng.uniform(0.0, duration, 3).tolist(), duration):
            assert piece.arcs(until) == ref.arcs(until)


def test_a_speed_too_small_to_multiply_moves_nothing_strange() -> None:
    # Found by `sensor-agent fuzz`: a command whose speed was a subnormal float (3.46e-322)
    # made a piece whose v·h underflowed to 0; the share of its distance divided by it, the
    # pose went NaN and the world stage raised. Now the share falls back to the turn's.
    stage = WorldStage(OPEN, rate_hz=20.0)
    stage.start(0.0)
    t = 0.0
    for v, w in [(0.0, 0.7), (0.0, -2.35), (3.46e-322, 0.99), (0.0, 1.0)]:
        t += 0.001
        stage.handle(topics.WHEEL_COMMAND, _wheel(v, w), t)
    for odometry, truth in _drive(stage, 1.0):
        assert np.isfinite([truth.x_m, truth.y_m, truth.yaw_rad, odometry.x_m]).all()
