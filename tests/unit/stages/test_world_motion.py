"""The world stage with motion: movers in world_truth, drifting odometry beside it."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from agent.errors import ConfigError
from agent.runtime import topics
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import Header, Message, Odometry, WheelCommand, WorldTruth, decode
from agent.runtime.stage import Output, Params
from agent.sim.movers import mover_states
from agent.sim.odometry import OdometryErrorModel
from agent.sim.world_file import load_world
from agent.stages.head_stage import HeadStage
from agent.stages.world_stage import WorldStage

REPO = Path(__file__).resolve().parents[3]
CROSSING = REPO / "worlds" / "crossing.toml"


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
    world = load_world(CROSSING)
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
    # 8 m driven: the odometry is off by centimetres to decimetres, and its covariance says so.
    assert odometry.distance_m == pytest.approx(8.0, rel=0.05)
    error = np.array([truth.x_m - odometry.x_m, truth.y_m - odometry.y_m])
    assert 1e-4 < float(np.hypot(*error)) < 1.0
    sigma = np.sqrt(np.diag(odometry.pose_covariance))
    assert np.all(sigma > 0.0) and sigma[0] < 1.0 and sigma[2] < 0.5
    variances = [np.trace(o.pose_covariance[:2, :2]) for o, _ in pairs[::20]]
    assert all(b > a for a, b in itertools.pairwise(variances))
    # Measured velocity: about the commanded one.
    assert odometry.speed_m_s == pytest.approx(0.4, rel=0.05)
    assert odometry.yaw_rate_rad_s == pytest.approx(0.1, rel=0.2)
    back = decode(odometry.to_wire())
    assert isinstance(back, Odometry)
    np.testing.assert_array_equal(back.pose_covariance, odometry.pose_covariance)


def _final_odometry(seed: int) -> tuple[float, float, float]:
    stage = WorldStage(load_world(CROSSING), rate_hz=20.0, command_timeout_s=100.0, seed=seed)
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
