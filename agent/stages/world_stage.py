"""The world simulator's stage: owns the ground truth.

Static obstacles come from the world file; the vehicle's true pose is integrated from the
wheel commands it receives (exact unicycle motion between commands). With no command, or
when the last one is older than ``command_timeout_s``, the vehicle stands still.

Inputs: ``wheel_command``. Outputs: ``world_truth`` at ``rate_hz``.
"""

from __future__ import annotations

import math

import numpy as np

from agent.kinematics.trajectory import ConstantTwist
from agent.runtime import topics
from agent.runtime.messages import Header, Message, WheelCommand, WorldTruth, stamp_ns
from agent.runtime.stage import Output, Params, Stage
from agent.sim.world import World
from agent.sim.world_file import load_world


class WorldStage(Stage):
    """Integrates the vehicle's true motion and publishes it.

    Parameters
    ----------
    world
        The world (its ``vehicle_pose`` is the start pose).
    rate_hz
        How often ``world_truth`` is published.
    command_timeout_s
        A wheel command older than this no longer moves the vehicle (it stops).
    max_speed_m_s, max_yaw_rate_rad_s
        Commands are clamped to the platform's limits (counted as ``clamped``).
    """

    def __init__(
        self,
        world: World,
        rate_hz: float = 50.0,
        command_timeout_s: float = 0.5,
        max_speed_m_s: float = 0.5,
        max_yaw_rate_rad_s: float = 1.5,
    ) -> None:
        if rate_hz <= 0 or command_timeout_s <= 0:
            raise ValueError("rate_hz and command_timeout_s must be positive")
        self.world = world
        self.period_s = 1.0 / rate_hz
        self.command_timeout_s = command_timeout_s
        self.max_speed = max_speed_m_s
        self.max_yaw_rate = max_yaw_rate_rad_s
        self.x, self.y, self.yaw = world.vehicle_pose
        self.speed = 0.0
        self.yaw_rate = 0.0
        self._time: float | None = None
        self._command_time = -math.inf
        self._next: float | None = None
        self._clamped = 0
        self._commands = 0

    @classmethod
    def from_params(cls, params: Params) -> WorldStage:
        stage = cls(
            load_world(params.string("world", "")),
            rate_hz=params.number("rate_hz", 50.0, lo=1.0, hi=1000.0),
            command_timeout_s=params.number("command_timeout_s", 0.5, lo=0.01),
            max_speed_m_s=params.number("max_speed_m_s", 0.5, lo=0.0),
            max_yaw_rate_rad_s=params.number("max_yaw_rate_rad_s", 1.5, lo=0.0),
        )
        params.check_all_read()
        return stage

    def start(self, now_s: float) -> list[Output]:
        self._time = now_s
        self._next = now_s
        return []

    def _advance(self, now_s: float) -> None:
        """Integrate the true motion up to ``now_s``; a command counts until it expires."""
        if self._time is None:
            self._time = now_s
        expiry = self._command_time + self.command_timeout_s
        moving_until = min(now_s, expiry)
        if moving_until > self._time and (self.speed != 0.0 or self.yaw_rate != 0.0):
            motion = ConstantTwist(self.x, self.y, self.yaw, self.speed, self.yaw_rate, 0.0)
            x, y, yaw = motion.poses_at(moving_until - self._time)
            self.x, self.y = float(x), float(y)
            self.yaw = math.remainder(float(yaw), math.tau)
        if now_s >= expiry:
            self.speed = self.yaw_rate = 0.0
        self._time = max(self._time, now_s)

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic != topics.WHEEL_COMMAND or not isinstance(msg, WheelCommand):
            return []
        self._advance(now_s)
        speed = min(max(msg.speed_m_s, -self.max_speed), self.max_speed)
        yaw_rate = min(max(msg.yaw_rate_rad_s, -self.max_yaw_rate), self.max_yaw_rate)
        self._clamped += (speed, yaw_rate) != (msg.speed_m_s, msg.yaw_rate_rad_s)
        self.speed, self.yaw_rate = speed, yaw_rate
        self._command_time = now_s
        self._commands += 1
        return []

    def tick(self, now_s: float) -> list[Output]:
        self._advance(now_s)
        self._next = (self._next if self._next is not None else now_s) + self.period_s
        if self._next <= now_s:  # fell behind (a stalled process): skip, do not burst
            self._next = now_s + self.period_s
        return [(topics.WORLD_TRUTH, self.truth(now_s))]

    def truth(self, now_s: float) -> WorldTruth:
        return WorldTruth(
            header=Header(stamp_ns=stamp_ns(now_s), frame_id="world"),
            x_m=self.x, y_m=self.y, yaw_rad=self.yaw, speed_m_s=self.speed,
            yaw_rate_rad_s=self.yaw_rate, world_name=self.world.name,
            mover_xy=np.zeros((0, 2)), mover_velocity_xy=np.zeros((0, 2)),
            mover_radius_m=np.zeros(0),
        )  # fmt: skip

    def next_tick_s(self) -> float | None:
        return self._next

    def counters(self) -> dict[str, int]:
        return {"wheel_commands": self._commands, "clamped": self._clamped}
