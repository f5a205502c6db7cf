"""The vehicle controller's stage: drives the vehicle on the environment vector alone.

Inputs: ``odometry`` (the base's wheel odometry, ``odom``) and ``environment`` (the agent's
vector). Outputs: ``vehicle_state`` for every odometry message (the odometry plus the path
the controller intends to drive, which the agent's sensor planner reads), and
``wheel_command`` every ``1/rate_hz`` s. It never reads truth: the task's goal is given in
the world frame, which is ``odom`` as it was at the start (:mod:`agent.sim.odometry`).

The logic is :class:`agent.control.controller.Controller`: it stops the vehicle (a zero
command) whenever it holds no valid vector (none yet, older than its ``valid_for_s``, or
``sensor_ok`` false). The stage adds one more guard of its own: no command but zero while no
odometry has come within ``odometry_timeout_s``.
"""

from __future__ import annotations

import math

import numpy as np

from agent.control.controller import (
    PLANNERS,
    Controller,
    ControlOutput,
    EnvironmentView,
    PlannerName,
    warm_up,
)
from agent.errors import ConfigError
from agent.kinematics.vehicle import VehicleSpec
from agent.runtime import topics
from agent.runtime.messages import (
    EnvironmentVector,
    Header,
    Message,
    Odometry,
    VehicleState,
    WheelCommand,
    stamp_ns,
)
from agent.runtime.stage import Output, Params, Stage
from agent.sim.world_file import load_world
from agent.task import Task


def environment_view(msg: EnvironmentVector) -> EnvironmentView:
    """The controller's view of one ``environment`` message (arrays shared, not copied)."""
    return EnvironmentView(
        stamp_s=msg.header.stamp_s, valid_for_s=msg.valid_for_s, sensor_ok=msg.sensor_ok,
        obstacle_id=msg.obstacle_id, kind=msg.kind, position_xy=msg.position_xy,
        velocity_xy=msg.velocity_xy, covariance=msg.covariance, extent=msg.extent,
        reflectivity=msg.reflectivity, free_bearing_rad=msg.free_bearing_rad,
        free_range_m=msg.free_range_m, free_far_m=msg.free_far_m, free_end_hit=msg.free_end_hit,
        free_far_from_m=msg.free_far_from_m, scan_window_rad=msg.scan_window_rad,
        scan_dark_m=msg.scan_dark_m, seen_range_m=msg.seen_range_m, seen_far_m=msg.seen_far_m,
        seen_end_hit=msg.seen_end_hit, across_sigma_m=msg.across_sigma_m,
        seen_age_s=msg.seen_age_s,
    )  # fmt: skip


class VehicleStage(Stage):
    """The vehicle controller (module docstring).

    Parameters
    ----------
    task
        What to do; the goal in the world frame (= ``odom`` at the start).
    planner
        ``"default"`` (the controller's local planner) or ``"dwa"`` (the dynamic window
        baseline).
    rate_hz
        How often a wheel command goes out.
    odometry_timeout_s
        Without odometry for this long, the command is zero.
    vehicle
        The vehicle's outline and limits.
    """

    def __init__(
        self,
        task: Task,
        planner: PlannerName = "default",
        rate_hz: float = 20.0,
        odometry_timeout_s: float = 0.3,
        vehicle: VehicleSpec | None = None,
    ) -> None:
        if planner not in PLANNERS:
            raise ValueError(f"planner must be one of {PLANNERS}, got {planner!r}")
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
        if not (math.isfinite(odometry_timeout_s) and odometry_timeout_s > 0.0):
            raise ValueError(f"odometry_timeout_s must be positive, got {odometry_timeout_s!r}")
        self.task = task
        self.spec = vehicle if vehicle is not None else VehicleSpec()
        self.controller = Controller(task, self.spec, planner=planner)
        self.period_s = 1.0 / rate_hz
        self.odometry_timeout_s = odometry_timeout_s
        self.last: ControlOutput | None = None
        self._next: float | None = None
        self._odometry_s: float | None = None
        self._intent = np.zeros((0, 2))
        self._counts: dict[str, int] = {
            "odometry": 0, "environments": 0, "environments_not_ok": 0, "wheel_commands": 0,
            "stopped_commands": 0, "stopped_no_odometry": 0, "environments_out_of_order": 0,
            "environments_malformed": 0,
        }  # fmt: skip
        self._environment_s: float | None = None

    @classmethod
    def from_params(cls, params: Params) -> VehicleStage:
        """Launch-file params: ``world`` (the world file whose ``[task]`` to do), ``planner``
        (``default`` or ``dwa``), ``rate_hz`` (20), ``odometry_timeout_s`` (0.3)."""
        path = params.string("world", "")
        world = load_world(path)
        if world.task is None:
            raise ConfigError(f"{path}: the world has no [task] for the vehicle to do")
        planner = params.string("planner", "default")
        if planner not in PLANNERS:
            raise ConfigError(
                f"process {params.process}: parameter 'planner' must be one of "
                f"{', '.join(PLANNERS)}, got {planner!r}"
            )
        stage = cls(
            world.task,
            planner="dwa" if planner == "dwa" else "default",
            rate_hz=params.number("rate_hz", 20.0, lo=1.0, hi=200.0),
            odometry_timeout_s=params.number("odometry_timeout_s", 0.3, lo=0.01, hi=10.0),
        )
        params.check_all_read()
        return stage

    # ------------------------------------------------------------------------- life cycle
    def prepare(self) -> None:
        """Load the controller's compiled kernels (a fraction of a second once cached)."""
        warm_up()

    def start(self, now_s: float) -> list[Output]:
        self.prepare()
        self._next = now_s
        return []

    def next_tick_s(self) -> float | None:
        return self._next

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic == topics.ODOMETRY and isinstance(msg, Odometry):
            return self._on_odometry(msg)
        if topic == topics.ENVIRONMENT and isinstance(msg, EnvironmentVector):
            self._counts["environments"] += 1
            self._counts["environments_not_ok"] += not msg.sensor_ok
            t = msg.header.stamp_s
            if self._environment_s is not None and t < self._environment_s:
                self._counts["environments_out_of_order"] += 1
                return []
            try:
                view = environment_view(msg)
            except ValueError:
                # Shapes the schema cannot state (a window of 0 or 2 bearings, a far
                # profile per bearing): dropped and counted, as a stale vector would be.
                self._counts["environments_malformed"] += 1
                return []
            self._environment_s = t
            self.controller.update_environment(view)
        return []

    def _on_odometry(self, msg: Odometry) -> list[Output]:
        self._counts["odometry"] += 1
        t = msg.header.stamp_s
        pose = np.array([msg.x_m, msg.y_m, msg.yaw_rad])
        self.controller.update_odometry(
            t, pose, msg.pose_covariance, msg.speed_m_s, msg.yaw_rate_rad_s
        )
        self._odometry_s = t if self._odometry_s is None else max(self._odometry_s, t)
        state = VehicleState(
            header=Header(stamp_ns=msg.header.stamp_ns, frame_id="odom"),
            x_m=msg.x_m, y_m=msg.y_m, yaw_rad=msg.yaw_rad, speed_m_s=msg.speed_m_s,
            yaw_rate_rad_s=msg.yaw_rate_rad_s, pose_covariance=msg.pose_covariance,
            intent_xy=self._intent, watch_xy=self.controller.watch_xy,
        )  # fmt: skip
        return [(topics.VEHICLE_STATE, state)]

    def tick(self, now_s: float) -> list[Output]:
        self._next = (self._next if self._next is not None else now_s) + self.period_s
        if self._next <= now_s:  # fell behind (a stalled process): skip, do not burst
            self._next = now_s + self.period_s
        out = self.controller.command(now_s)
        self.last = out
        speed, yaw_rate = out.speed_m_s, out.yaw_rate_rad_s
        if self._odometry_s is None or now_s - self._odometry_s > self.odometry_timeout_s:
            if speed != 0.0 or yaw_rate != 0.0:
                self._counts["stopped_no_odometry"] += 1
            speed = yaw_rate = 0.0
        self._intent = np.ascontiguousarray(out.intent_xy, dtype=np.float64).reshape(-1, 2)
        self._counts["wheel_commands"] += 1
        self._counts["stopped_commands"] += speed == 0.0 and yaw_rate == 0.0
        mode = f"mode_{out.mode}"
        self._counts[mode] = self._counts.get(mode, 0) + 1
        if out.reason:
            reason = f"reason_{out.reason}"
            self._counts[reason] = self._counts.get(reason, 0) + 1
        command = WheelCommand(
            header=Header(stamp_ns=stamp_ns(now_s), frame_id="base_link"),
            speed_m_s=speed, yaw_rate_rad_s=yaw_rate,
        )  # fmt: skip
        return [(topics.WHEEL_COMMAND, command)]

    def counters(self) -> dict[str, int]:
        return dict(self._counts)
