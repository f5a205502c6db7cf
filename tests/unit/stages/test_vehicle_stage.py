"""The vehicle controller's stage: relays odometry as the vehicle state with its intent, and
commands nothing but zero without a valid environment vector or without odometry."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agent.errors import ConfigError
from agent.runtime import topics
from agent.runtime.messages import (
    EnvironmentVector,
    Header,
    Odometry,
    VehicleState,
    WheelCommand,
    stamp_ns as ns,
)
from agent.runtime.stage import Params
from agent.stages.vehicle_stage import VehicleStage
from agent.task import Task

ROOT = Path(__file__).resolve().parents[3]


def _odometry(t: float, x: float = 0.0) -> Odometry:
    return Odometry(
        header=Header(stamp_ns=ns(t), frame_id="odom"), x_m=x, y_m=0.0, yaw_rad=0.0,
        speed_m_s=0.0, yaw_rate_rad_s=0.0, pose_covariance=np.eye(3) * 1e-6,
    )  # fmt: skip


def _environment(t: float, ok: bool = True, free_m: float = 2.5) -> EnvironmentVector:
    bearings = np.radians(np.arange(-180.0, 180.0, 1.0))
    free = np.where(np.abs(bearings) <= np.radians(20.0), free_m, 0.0)
    return EnvironmentVector(
        header=Header(stamp_ns=ns(t), frame_id="odom"),
        obstacle_id=np.zeros(0, dtype=np.int64), kind=np.zeros(0, dtype=np.uint8),
        position_xy=np.zeros((0, 2)), velocity_xy=np.zeros((0, 2)),
        covariance=np.zeros((0, 4, 4)), extent=np.zeros((0, 4)), reflectivity=np.zeros(0),
        free_bearing_rad=bearings, free_range_m=free, sensor_ok=ok, valid_for_s=0.3,
    )  # fmt: skip


def _command(stage: VehicleStage, t: float) -> WheelCommand:
    (topic, msg), *_ = stage.tick(t)
    assert topic == topics.WHEEL_COMMAND and isinstance(msg, WheelCommand)
    return msg


def _drive(stage: VehicleStage, until_s: float, env_ok: bool = True) -> list[WheelCommand]:
    """Odometry at 20 Hz, vectors at 10 Hz (fresh), a command every tick."""
    commands = []
    t = 0.0
    while t <= until_s + 1e-9:
        stage.handle(topics.ODOMETRY, _odometry(t), t)
        if round(t * 20) % 2 == 0:
            stage.handle(topics.ENVIRONMENT, _environment(t, env_ok), t)
        commands.append(_command(stage, t))
        t += 0.05
    return commands


def test_odometry_goes_out_as_the_vehicle_state() -> None:
    stage = VehicleStage(Task("goto", (3.0, 0.0)))
    stage.start(0.0)
    ((topic, msg),) = stage.handle(topics.ODOMETRY, _odometry(0.5, x=0.2), 0.5)
    assert topic == topics.VEHICLE_STATE and isinstance(msg, VehicleState)
    assert msg.x_m == 0.2 and msg.header.stamp_ns == ns(0.5) and msg.intent_xy.shape[1] == 2


def test_no_vector_no_motion_and_a_stale_one_stops_it() -> None:
    stage = VehicleStage(Task("goto", (3.0, 0.0)))
    stage.start(0.0)
    stage.handle(topics.ODOMETRY, _odometry(0.0), 0.0)
    first = _command(stage, 0.0)
    assert (first.speed_m_s, first.yaw_rate_rad_s) == (0.0, 0.0)  # no vector yet
    commands = _drive(stage, 3.0)
    # It moves on fresh vectors (it looks round first: it turns on the spot).
    assert any(abs(c.yaw_rate_rad_s) > 0.1 for c in commands)
    # Vectors stop; odometry goes on. At 0.3 s past the last vector's stamp the command is 0.
    t_last = 3.0
    for k in range(1, 12):
        t = t_last + 0.05 * k
        stage.handle(topics.ODOMETRY, _odometry(t), t)
        command = _command(stage, t)
        if t > t_last + 0.3 + 1e-9:
            assert (command.speed_m_s, command.yaw_rate_rad_s) == (0.0, 0.0), t


def test_an_untrusted_vector_stops_it() -> None:
    stage = VehicleStage(Task("goto", (3.0, 0.0)))
    stage.start(0.0)
    commands = _drive(stage, 1.0, env_ok=False)
    assert all((c.speed_m_s, c.yaw_rate_rad_s) == (0.0, 0.0) for c in commands)
    assert stage.counters()["environments_not_ok"] > 0


def test_without_odometry_the_command_is_zero() -> None:
    stage = VehicleStage(Task("goto", (3.0, 0.0)), odometry_timeout_s=0.3)
    stage.start(0.0)
    _drive(stage, 2.0)
    for k in range(1, 10):  # vectors keep coming, odometry does not
        t = 2.0 + 0.1 * k
        stage.handle(topics.ENVIRONMENT, _environment(t), t)
        command = _command(stage, t)
        if t > 2.0 + 0.3 + 1e-9:
            assert (command.speed_m_s, command.yaw_rate_rad_s) == (0.0, 0.0), t


def test_a_world_without_a_task_is_refused() -> None:
    with pytest.raises(ConfigError, match="no \\[task\\]"):
        VehicleStage.from_params(Params("vehicle", {"world": str(ROOT / "worlds" / "office.toml")}))
    with pytest.raises(ConfigError, match="planner"):
        VehicleStage.from_params(
            Params("vehicle", {"world": str(ROOT / "worlds" / "demo.toml"), "planner": "x"})
        )
