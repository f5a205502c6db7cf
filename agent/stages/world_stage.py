"""The world simulator's stage: owns the ground truth, and the base's drifting odometry.

Static obstacles and movers come from the world file; the vehicle's true pose is integrated
from the wheel commands it receives (exact unicycle motion between commands). With no
command, or when the last one is older than ``command_timeout_s``, the vehicle stands still.
The movers are where :func:`agent.sim.movers.mover_states` puts them at the stamp (the graph
clock, which the simulated head reads too).

The base's wheel odometry (:mod:`agent.sim.odometry`) integrates the same true motion through
encoders with wheel-scale, track and slip errors (drawn from ``seed``), starting at the world's
start pose with no error (so ``odom`` is the world frame as it was at the start).

Inputs: ``wheel_command``. Outputs, at ``rate_hz``: ``odometry`` (frame ``odom``), then
``world_truth`` (frame ``world``, with the movers' true centres, velocities and radii).
"""

from __future__ import annotations

import math

import numpy as np

from agent.kinematics.trajectory import ConstantTwist
from agent.runtime import topics
from agent.runtime.messages import (
    Header,
    Message,
    Odometry,
    WheelCommand,
    WorldTruth,
    stamp_ns,
)
from agent.runtime.stage import Output, Params, Stage
from agent.sim.movers import mover_states
from agent.sim.odometry import OdometryErrorModel, WheelOdometry
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
    seed
        Seeds the odometry's errors (systematic ones drawn once, slip every step).
    odometry
        The odometry's error model (defaults and their sources in :mod:`agent.sim.odometry`).
    """

    def __init__(
        self,
        world: World,
        rate_hz: float = 50.0,
        command_timeout_s: float = 0.5,
        max_speed_m_s: float = 0.5,
        max_yaw_rate_rad_s: float = 1.5,
        seed: int = 0,
        odometry: OdometryErrorModel | None = None,
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
        self.odometry = WheelOdometry(
            odometry if odometry is not None else OdometryErrorModel(),
            np.random.default_rng(seed),
            world.vehicle_pose,
        )
        self._odometry_time: float | None = None  # when odometry was last published
        self._mover_radius = np.array([m.radius_m for m in world.movers], dtype=np.float64)

    @classmethod
    def from_params(cls, params: Params) -> WorldStage:
        """Launch-file params: ``world``, ``rate_hz``, ``command_timeout_s``,
        ``max_speed_m_s``, ``max_yaw_rate_rad_s``, ``seed`` and the odometry's error model:
        ``wheel_track_m`` (0.5), ``wheel_scale_sigma`` (0.015), ``wheel_ratio_sigma``
        (0.015), ``wheel_track_sigma`` (0.02), ``wheel_slip_m`` (1e-5 m²/m)."""
        default = OdometryErrorModel()
        odometry = OdometryErrorModel(
            track_m=params.number("wheel_track_m", default.track_m, lo=0.05, hi=10.0),
            scale_sigma=params.number("wheel_scale_sigma", default.scale_sigma, 0.0, 0.2),
            ratio_sigma=params.number("wheel_ratio_sigma", default.ratio_sigma, 0.0, 0.2),
            track_sigma=params.number("wheel_track_sigma", default.track_sigma, 0.0, 0.2),
            slip_m=params.number("wheel_slip_m", default.slip_m, 0.0, 0.01),
        )
        stage = cls(
            load_world(params.string("world", "")),
            rate_hz=params.number("rate_hz", 50.0, lo=1.0, hi=1000.0),
            command_timeout_s=params.number("command_timeout_s", 0.5, lo=0.01),
            max_speed_m_s=params.number("max_speed_m_s", 0.5, lo=0.0),
            max_yaw_rate_rad_s=params.number("max_yaw_rate_rad_s", 1.5, lo=0.0),
            seed=params.integer("seed", 0),
            odometry=odometry,
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
            dt = moving_until - self._time
            motion = ConstantTwist(self.x, self.y, self.yaw, self.speed, self.yaw_rate, 0.0)
            x, y, yaw = motion.poses_at(dt)
            self.x, self.y = float(x), float(y)
            self.yaw = math.remainder(float(yaw), math.tau)
            self.odometry.advance(self.speed * dt, self.yaw_rate * dt)
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
        return [
            (topics.ODOMETRY, self.odometry_message(now_s)),
            (topics.WORLD_TRUTH, self.truth(now_s)),
        ]

    def truth(self, now_s: float) -> WorldTruth:
        """The truth at ``now_s`` (the vehicle as last integrated; the movers at ``now_s``)."""
        mover_xy, mover_vxy = mover_states(self.world.movers, now_s)
        return WorldTruth(
            header=Header(stamp_ns=stamp_ns(now_s), frame_id="world"),
            x_m=self.x, y_m=self.y, yaw_rad=self.yaw, speed_m_s=self.speed,
            yaw_rate_rad_s=self.yaw_rate, world_name=self.world.name,
            mover_xy=mover_xy.reshape(-1, 2), mover_velocity_xy=mover_vxy.reshape(-1, 2),
            mover_radius_m=self._mover_radius,
        )  # fmt: skip

    def odometry_message(self, now_s: float) -> Odometry:
        """The odometry at ``now_s``: pose and covariance as integrated so far, velocity the
        wheels' measured motion since the last message over the time since then (0 for the
        first message)."""
        moved = self.odometry.take_motion()[0]
        elapsed = 0.0 if self._odometry_time is None else now_s - self._odometry_time
        self._odometry_time = now_s
        speed, yaw_rate = (moved / elapsed).tolist() if elapsed > 0.0 else (0.0, 0.0)
        x, y, yaw = self.odometry.pose[0].tolist()
        return Odometry(
            header=Header(stamp_ns=stamp_ns(now_s), frame_id="odom"),
            x_m=x, y_m=y, yaw_rad=math.remainder(yaw, math.tau), speed_m_s=speed,
            yaw_rate_rad_s=yaw_rate, pose_covariance=self.odometry.pose_covariance[0],
            distance_m=float(self.odometry.distance_m[0]),
        )  # fmt: skip

    def next_tick_s(self) -> float | None:
        return self._next

    def counters(self) -> dict[str, int]:
        return {"wheel_commands": self._commands, "clamped": self._clamped}
