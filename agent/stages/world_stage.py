"""The world simulator's stage: owns the ground truth, and the base's drifting odometry.

Static obstacles and movers come from the world file; the vehicle's true pose is integrated
from the wheel commands it receives. Commands are clamped to the vehicle's speed and yaw-rate
limits (:class:`~agent.kinematics.vehicle.VehicleSpec`), and the true speed and yaw rate move
toward the command at most ``max_accel_m_s2`` and ``max_yaw_accel_rad_s2`` per second (braking
too). Between changes the motion is exact (a unicycle: straight line or circular arc); while
speed or yaw rate ramp, it is integrated in steps of at most :data:`MAX_INTEGRATION_STEP_S`,
each an arc at the step's mean speed and yaw rate, so that distance and heading are exact and
the position is right to ``O(a·ω·h³)`` (micrometres). With no command, or when the last one
is older than ``command_timeout_s``, the command is zero: the vehicle brakes to a stop. The
movers are where :func:`agent.sim.movers.mover_states` puts them at the stamp (the graph
clock, which the simulated head reads too); they walk their paths blindly.

Collisions: after every step the vehicle's outline is tested against the true world
(:mod:`agent.sim.footprint`), at sub-steps short enough that neither the outline nor a mover
moves more than :data:`MAX_SUBSTEP_M` (2 cm) between tests, so nothing tunnels through a thin
wall. At the first contact (clearance 0; its time found to within 1/4096 of a sub-step) the
vehicle stops for good: speed and yaw rate 0, later commands ignored and counted
(``commands_ignored``). The collision is the vehicle's (``"vehicle"``) if its outline's
fastest point moved faster than ``VehicleSpec.moving_speed_m_s`` (speed and turning together)
or the obstacle is static, else the mover's (``"mover"``: a mover ran into a stopped vehicle).
The least clearance so far is kept. A start pose already in contact is a collision at the start.

The base's wheel odometry (:mod:`agent.sim.odometry`) integrates the same true motion through
encoders with wheel-scale, track and slip errors (drawn from ``seed``), starting at the world's
start pose with no error (so ``odom`` is the world frame as it was at the start).

Inputs: ``wheel_command``. Outputs, at ``rate_hz``: ``odometry`` (frame ``odom``), then
``world_truth`` (frame ``world``, with the movers' true centres, velocities and radii, the
outline's clearance and any collision). In-process users (the lock-step evaluation) read the
same as attributes: :attr:`WorldStage.collision`, ``collision_time_s``,
``collision_obstacle``, ``clearance_m``, ``min_clearance_m``.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from agent.arrays import FloatArray
from agent.kinematics.vehicle import VehicleSpec
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
from agent.sim.footprint import IntArray, outline_clearances
from agent.sim.movers import Mover, mover_states
from agent.sim.odometry import OdometryErrorModel, WheelOdometry
from agent.sim.world import World
from agent.sim.world_file import load_world
from agent.stages.world_motion_kernels import piece_arcs, piece_nodes, piece_poses

__all__ = ["MAX_INTEGRATION_STEP_S", "MAX_REPORTED_CLEARANCE_M", "MAX_SUBSTEP_M", "WorldStage"]

MAX_SUBSTEP_M = 0.02
"""Most the outline or a mover moves between two collision tests, metres."""
MAX_INTEGRATION_STEP_S = 0.05
"""Longest step of the integration while speed or yaw rate ramp, seconds."""
MAX_REPORTED_CLEARANCE_M = 100.0
"""``world_truth`` caps clearances here (its floats are finite; nothing in the world: inf)."""
_CONTACT_BISECTIONS = 12
"""Halvings of the sub-step that ends in contact: the contact time to 1/4096 of it."""


class WorldStage(Stage):
    """Integrates the vehicle's true motion, checks it for collisions, and publishes it.

    Parameters
    ----------
    world
        The world (its ``vehicle_pose`` is the start pose).
    rate_hz
        How often ``world_truth`` is published.
    command_timeout_s
        A wheel command older than this no longer drives the vehicle (it brakes to a stop).
    max_speed_m_s, max_yaw_rate_rad_s
        Commands are clamped to these (counted as ``clamped``); default the vehicle's.
    seed
        Seeds the odometry's errors (systematic ones drawn once, slip every step).
    odometry
        The odometry's error model (defaults and their sources in :mod:`agent.sim.odometry`).
    vehicle
        The outline and limits (default :class:`VehicleSpec` ``()``).
    max_accel_m_s2, max_yaw_accel_rad_s2
        The limits on the change of speed and of yaw rate; default the vehicle's; ``inf``:
        the command takes effect at once.

    Attributes
    ----------
    x, y, yaw, speed, yaw_rate
        The true pose (m, m, rad in (-π, π]) and velocity (m/s, rad/s), world frame.
    clearance_m, min_clearance_m
        The outline's clearance as last integrated, and the least so far (m; ``inf`` with
        nothing in the world).
    collision
        ``""`` (none yet), ``"vehicle"`` or ``"mover"``: who moved into whom.
    collision_obstacle
        The obstacle's id (:mod:`agent.sim.world`; movers after the static ones), -1 if none.
    collision_time_s
        When the outline first touched it (graph clock), NaN if never.
    """

    def __init__(
        self,
        world: World,
        rate_hz: float = 50.0,
        command_timeout_s: float = 0.5,
        max_speed_m_s: float | None = None,
        max_yaw_rate_rad_s: float | None = None,
        seed: int = 0,
        odometry: OdometryErrorModel | None = None,
        vehicle: VehicleSpec | None = None,
        max_accel_m_s2: float | None = None,
        max_yaw_accel_rad_s2: float | None = None,
    ) -> None:
        if not (rate_hz > 0 and command_timeout_s > 0):
            raise ValueError("rate_hz and command_timeout_s must be positive")
        spec = vehicle if vehicle is not None else VehicleSpec()
        self.vehicle = spec
        self.max_speed = spec.max_speed_m_s if max_speed_m_s is None else max_speed_m_s
        self.max_yaw_rate = (
            spec.max_yaw_rate_rad_s if max_yaw_rate_rad_s is None else max_yaw_rate_rad_s
        )
        self.max_accel = spec.max_accel_m_s2 if max_accel_m_s2 is None else max_accel_m_s2
        self.max_yaw_accel = (
            spec.max_yaw_accel_rad_s2 if max_yaw_accel_rad_s2 is None else max_yaw_accel_rad_s2
        )
        for name, value in (("max_speed_m_s", self.max_speed),
                            ("max_yaw_rate_rad_s", self.max_yaw_rate)):  # fmt: skip
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        for name, value in (("max_accel_m_s2", self.max_accel),
                            ("max_yaw_accel_rad_s2", self.max_yaw_accel)):  # fmt: skip
            if not value > 0.0:
                raise ValueError(f"{name} must be > 0 (inf: no limit), got {value!r}")
        self.world = world
        self.period_s = 1.0 / rate_hz
        self.command_timeout_s = command_timeout_s
        self.x, self.y, self.yaw = world.vehicle_pose
        self.speed = 0.0
        self.yaw_rate = 0.0
        self.command_speed = 0.0  # the command in force (clamped), m/s
        self.command_yaw_rate = 0.0  # rad/s
        self.clearance_m = math.inf
        self.min_clearance_m = math.inf
        self.collision = ""
        self.collision_obstacle = -1
        self.collision_time_s = math.nan
        self._time: float | None = None
        self._command_time = -math.inf
        self._next: float | None = None
        self._clamped = 0
        self._commands = 0
        self._ignored = 0
        self.odometry = WheelOdometry(
            odometry if odometry is not None else OdometryErrorModel(),
            np.random.default_rng(seed),
            world.vehicle_pose,
        )
        self._odometry_time: float | None = None  # when odometry was last published
        self._mover_radius = np.array([m.radius_m for m in world.movers], dtype=np.float64)
        self._mover_speed = max((m.speed_m_s for m in world.movers), default=0.0)
        none = np.zeros((0, 2))
        self._movers_at: tuple[float, FloatArray, FloatArray] = (math.nan, none, none)

    @classmethod
    def from_params(cls, params: Params) -> WorldStage:
        """Launch-file params: ``world``, ``rate_hz``, ``command_timeout_s``,
        ``max_speed_m_s``, ``max_yaw_rate_rad_s``, ``max_accel_m_s2``,
        ``max_yaw_accel_rad_s2`` (the vehicle's limits: 0.5, 1.5, 0.5, 2.0), ``seed`` and the
        odometry's error model: ``wheel_track_m`` (0.5), ``wheel_scale_sigma`` (0.015),
        ``wheel_ratio_sigma`` (0.015), ``wheel_track_sigma`` (0.02), ``wheel_slip_m``
        (1e-5 m²/m)."""
        default = OdometryErrorModel()
        spec = VehicleSpec()
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
            max_speed_m_s=params.number("max_speed_m_s", spec.max_speed_m_s, lo=0.0),
            max_yaw_rate_rad_s=params.number("max_yaw_rate_rad_s", spec.max_yaw_rate_rad_s, 0.0),
            seed=params.integer("seed", 0),
            odometry=odometry,
            max_accel_m_s2=params.number("max_accel_m_s2", spec.max_accel_m_s2, lo=1e-3),
            max_yaw_accel_rad_s2=params.number(
                "max_yaw_accel_rad_s2", spec.max_yaw_accel_rad_s2, lo=1e-3
            ),
        )
        params.check_all_read()
        return stage

    def prepare(self) -> None:
        """Load the compiled kernels (:func:`load_kernels`; a fraction of a second once
        cached, once per process)."""
        load_kernels()

    def start(self, now_s: float) -> list[Output]:
        self.prepare()
        self._begin(now_s)
        self._next = now_s
        return []

    # ----------------------------------------------------------------------------------------
    # Motion
    # ----------------------------------------------------------------------------------------

    def _begin(self, now_s: float) -> float:
        """Start the clock at ``now_s`` and test the start pose, unless started; return the
        time integrated to."""
        if self._time is not None:
            return self._time
        self._time = now_s
        d, ids = self._clearances(np.array([[self.x, self.y, self.yaw]]), np.array([now_s]))
        self.clearance_m = self.min_clearance_m = float(d[0])
        if d[0] <= 0.0:
            self._collide(now_s, int(ids[0]))
        return now_s

    def _advance(self, now_s: float) -> None:
        """Integrate the true motion up to ``now_s`` (a command counts until it expires, and
        speed and yaw rate ramp toward it), testing the outline for contact on the way."""
        started = t = self._begin(now_s)
        if t >= now_s:
            return
        if self.collision:  # standing still for good; the movers walk on
            d, _ = self._clearances(np.array([[self.x, self.y, self.yaw]]), np.array([now_s]))
            self.clearance_m = float(d[0])
            self._time = now_s
            return
        pieces = self._plan(t, now_s)
        # Every piece's sub-steps tested at once, and the pieces then taken up to the first
        # contact, if any.
        taus = [_substeps(piece, self.vehicle.circumradius_m, self._mover_speed)
                for _, piece in pieces]  # fmt: skip
        counts = [tau.size for tau in taus]
        if sum(counts):
            poses = np.concatenate(
                [piece.poses(tau) for (_, piece), tau in zip(pieces, taus, strict=True)]
            )
            times = np.concatenate([t0 + tau for (t0, _), tau in zip(pieces, taus, strict=True)])
            d, ids = self._clearances(poses, times)
        else:  # nothing moves: the clearance stays
            d, ids = np.zeros(0), np.zeros(0, dtype=np.int64)
        touched = np.flatnonzero(d <= 0.0)
        end = int(touched[0]) if touched.size else d.size  # sub-steps clear before contact
        if end:
            self.min_clearance_m = min(self.min_clearance_m, float(d[:end].min()))
        first = 0
        for (t0, piece), tau, count in zip(pieces, taus, counts, strict=True):
            if first + count <= end:  # clear all through
                self._commit(piece, piece.duration)
                first += count
                continue
            i = end - first  # contact within this piece's sub-step i, clear at its start
            lo, hi = (float(tau[i - 1]) if i else 0.0), float(tau[i])
            obstacle = int(ids[end])
            for _ in range(_CONTACT_BISECTIONS):
                mid = 0.5 * (lo + hi)
                dm, im = self._clearances(piece.poses(np.array([mid])), np.array([t0 + mid]))
                if dm[0] <= 0.0:
                    hi, obstacle = mid, int(im[0])
                else:
                    lo = mid
            self._commit(piece, hi)
            self._collide(t0 + hi, obstacle)
            break
        if not self.collision and d.size:
            self.clearance_m = float(d[-1])
        self._time = max(started, now_s)

    def _plan(self, t: float, now_s: float) -> list[tuple[float, _Piece]]:
        """The motion from ``t`` to ``now_s``: pieces (start time, piece) over which speed and
        yaw rate each ramp at their limit toward the command in force, or hold."""
        pieces = []
        pose = (self.x, self.y, self.yaw)
        v, w = self.speed, self.yaw_rate
        while t < now_s:
            expiry = self._command_time + self.command_timeout_s
            if t < expiry:
                target_v, target_w, end = self.command_speed, self.command_yaw_rate, expiry
            else:
                target_v, target_w, end = 0.0, 0.0, math.inf
            end = min(end, now_s)
            reach_v = t + abs(target_v - v) / self.max_accel
            reach_w = t + abs(target_w - w) / self.max_yaw_accel
            if reach_v <= t:  # there already (or, with no limit, at once): exactly
                v = target_v
            if reach_w <= t:
                w = target_w
            stop = min(end, reach_v if reach_v > t else end, reach_w if reach_w > t else end)
            av = math.copysign(self.max_accel, target_v - v) if reach_v > t else 0.0
            aw = math.copysign(self.max_yaw_accel, target_w - w) if reach_w > t else 0.0
            piece = _Piece(pose, v, w, av, aw, stop - t)
            pieces.append((t, piece))
            pose = piece.end
            v = target_v if stop >= reach_v else v + av * (stop - t)
            w = target_w if stop >= reach_w else w + aw * (stop - t)
            piece.speed_end, piece.yaw_rate_end = v, w
            t = stop
        return pieces

    def _commit(self, piece: _Piece, until: float) -> None:
        """Take the state ``until`` seconds into ``piece`` as the truth, and move the odometry
        through the same arcs."""
        for distance, turn in piece.arcs(until):
            self.odometry.advance(distance, turn)
        if until >= piece.duration:
            x, y, yaw = piece.end
            self.speed, self.yaw_rate = piece.speed_end, piece.yaw_rate_end
        else:
            x, y, yaw = piece.poses(np.array([until]))[0].tolist()
            self.speed, self.yaw_rate = piece.rates_at(until)
        self.x, self.y = x, y
        self.yaw = math.remainder(yaw, math.tau)

    def _collide(self, t: float, obstacle: int) -> None:
        """Record the first contact, at ``t`` with ``obstacle``, and stop for good."""
        hl, hw = 0.5 * self.vehicle.length_m, 0.5 * self.vehicle.width_m
        fastest = math.hypot(abs(self.speed) + abs(self.yaw_rate) * hw, self.yaw_rate * hl)
        is_mover = obstacle >= self.world.mover_id_base
        moving = fastest > self.vehicle.moving_speed_m_s
        self.collision = "vehicle" if moving or not is_mover else "mover"
        self.collision_obstacle = obstacle
        self.collision_time_s = t
        self.clearance_m = self.min_clearance_m = 0.0
        self.speed = self.yaw_rate = 0.0
        self.command_speed = self.command_yaw_rate = 0.0

    def _clearances(self, poses: FloatArray, times: FloatArray) -> tuple[FloatArray, IntArray]:
        """Clearance (k,) and obstacle (k,) of the outline at ``poses`` (k, 3) at ``times``."""
        if not self.world.movers:
            return outline_clearances(self.world, poses, vehicle=self.vehicle)
        xy, vxy = mover_states(self.world.movers, times)  # (m, k, 2)
        self._movers_at = (float(times[-1]), xy[:, -1], vxy[:, -1])  # for truth() at that time
        return outline_clearances(
            self.world, poses, np.swapaxes(xy, 0, 1), self._mover_radius, self.vehicle
        )

    # ----------------------------------------------------------------------------------------
    # The stage
    # ----------------------------------------------------------------------------------------

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic != topics.WHEEL_COMMAND or not isinstance(msg, WheelCommand):
            return []
        self._advance(now_s)
        self._commands += 1
        if self.collision:
            self._ignored += 1
            return []
        speed = min(max(msg.speed_m_s, -self.max_speed), self.max_speed)
        yaw_rate = min(max(msg.yaw_rate_rad_s, -self.max_yaw_rate), self.max_yaw_rate)
        self._clamped += (speed, yaw_rate) != (msg.speed_m_s, msg.yaw_rate_rad_s)
        self.command_speed, self.command_yaw_rate = speed, yaw_rate
        if math.isinf(self.max_accel):
            self.speed = speed
        if math.isinf(self.max_yaw_accel):
            self.yaw_rate = yaw_rate
        self._command_time = now_s
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
        at, mover_xy, mover_vxy = self._movers_at
        if at != now_s:
            mover_xy, mover_vxy = mover_states(self.world.movers, now_s)
        return WorldTruth(
            header=Header(stamp_ns=stamp_ns(now_s), frame_id="world"),
            x_m=self.x, y_m=self.y, yaw_rad=self.yaw, speed_m_s=self.speed,
            yaw_rate_rad_s=self.yaw_rate, world_name=self.world.name,
            mover_xy=mover_xy.reshape(-1, 2), mover_velocity_xy=mover_vxy.reshape(-1, 2),
            mover_radius_m=self._mover_radius,
            clearance_m=min(self.clearance_m, MAX_REPORTED_CLEARANCE_M),
            min_clearance_m=min(self.min_clearance_m, MAX_REPORTED_CLEARANCE_M),
            collision=self.collision, collision_obstacle=self.collision_obstacle,
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
        out = {"wheel_commands": self._commands, "clamped": self._clamped}
        if self._ignored:  # after a collision only
            out["commands_ignored"] = self._ignored
        return out


class _Piece:
    """Motion from a pose with speed and yaw rate changing linearly over ``duration`` s.

    It is integrated in steps of at most :data:`MAX_INTEGRATION_STEP_S` (one step when speed
    and yaw rate hold), each the arc at its mean speed and yaw rate: the distance and turn of
    each step are exact, the path within it right to ``O(a·ω·h³)`` (micrometres), and the
    odometry reads the very same arcs. Within a step the pose has gone the exact distance
    along its arc (or, turning on the spot, the exact turn). With speed and yaw rate constant
    the arc is the exact unicycle motion.
    """

    def __init__(
        self,
        start: tuple[float, float, float],
        v0: float,
        w0: float,
        av: float,
        aw: float,
        duration: float,
    ) -> None:
        self.duration = duration
        self.ramps = av != 0.0 or aw != 0.0
        n = max(1, math.ceil(duration / MAX_INTEGRATION_STEP_S)) if self.ramps else 1
        # times (n + 1,) from 0; each step's mean speed (m/s) and yaw rate (rad/s); the pose
        # (n + 1, 3) at each step's start, and the end.
        self.times, self.speed, self.yaw_rate, self.nodes = piece_nodes(
            start[0], start[1], start[2], v0, w0, av, aw, duration, n
        )
        self._v0, self._w0, self._av, self._aw = v0, w0, av, aw
        x, y, yaw = self.nodes[-1].tolist()
        self.end: tuple[float, float, float] = (x, y, yaw)
        self.speed_end, self.yaw_rate_end = v0 + av * duration, w0 + aw * duration
        # The fastest the outline's farthest point and the movers can go (for sub-steps).
        self.fastest_speed = max(abs(v0), abs(self.speed_end))
        self.fastest_yaw_rate = max(abs(w0), abs(self.yaw_rate_end))

    def rates_at(self, tau: float) -> tuple[float, float]:
        """Speed (m/s) and yaw rate (rad/s) ``tau`` seconds into the piece."""
        return self._v0 + self._av * tau, self._w0 + self._aw * tau

    def poses(self, tau: FloatArray) -> FloatArray:
        """Poses (q, 3) at times ``tau`` (q,) from the piece's start, within it.

        How far along its arc the step is after ``dt``: the share of its distance truly gone
        (``v(t0)·dt + a·dt²/2`` of ``v_mean·h``) if the speed keeps its sign through the
        step, else the share of its turn if the yaw rate does, else of its time
        (:func:`agent.stages.world_motion_kernels.piece_poses`)."""
        return piece_poses(
            self.times, self.speed, self.yaw_rate, self.nodes,
            self._v0, self._w0, self._av, self._aw, np.ascontiguousarray(tau, dtype=np.float64),
        )  # fmt: skip

    def arcs(self, until: float) -> list[tuple[float, float]]:
        """(distance_m, turn_rad) of each arc driven in the first ``until`` seconds."""
        driven: list[tuple[float, float]] = [
            (d, t) for d, t in piece_arcs(self.times, self.speed, self.yaw_rate, until).tolist()
        ]
        return driven


def _substeps(piece: _Piece, reach_m: float, mover_speed_m_s: float) -> FloatArray:
    """Times (k,) from the piece's start, its end the last, at which to test the outline: so
    that neither it (its points at most ``reach_m`` from its centre) nor a mover (at most
    ``mover_speed_m_s``) moves more than :data:`MAX_SUBSTEP_M` between tests. Empty if
    nothing moves."""
    fastest = piece.fastest_speed + reach_m * piece.fastest_yaw_rate
    if fastest == 0.0 and mover_speed_m_s == 0.0:
        return np.zeros(0)
    k = max(1, math.ceil(max(fastest, mover_speed_m_s) * piece.duration / MAX_SUBSTEP_M))
    return piece.duration * np.arange(1, k + 1) / k


@functools.cache
def load_kernels() -> None:
    """Load the compiled loops of the motion, the outline's clearance, the movers' places and
    the odometry (compiling them on the first use on this machine: about 10 s)."""
    world = World.build(
        walls=[(((2.0, -1.0), (2.0, 1.0)), 1.0)],
        cylinders=[((-2.0, 0.0), 0.1, 1.0)],
        movers=[Mover(0.1, 1.0, np.array([[0.0, 2.0], [1.0, 2.0]]), 0.5)],
    )
    piece = _Piece((0.0, 0.0, 0.0), 0.1, 0.2, 0.5, -0.5, 0.1)
    poses = piece.poses(np.array([0.05, 0.1]))
    piece.arcs(0.05)
    xy, _ = mover_states(world.movers, np.array([0.05, 0.1]))
    outline_clearances(world, poses, np.swapaxes(xy, 0, 1), np.array([0.1]))
    WheelOdometry(OdometryErrorModel(), np.random.default_rng(0), (0.0, 0.0, 0.0)).advance(
        0.01, 0.01
    )
