"""``sensor-agent bench tracking``: the agent's tracks and free space scored against truth.

Each scene is a random dynamic world (:func:`agent.sim.worldgen.tracking_scene`: walls,
boxes, cylinders, 0-3 movers at up to 0.8 m/s) and a path of 8-15 m that the vehicle drives
at 0.4 m/s (a 20-40 s drive, cut at ``MAX_SCENE_S``), its odometry drifting. The graph runs
in lock-step (:mod:`agent.runtime.lockstep`), every message through its wire encoding:
the world simulator, a scripted driver (:class:`ScriptedDriver`), the simulated head,
calibration, filtering, features, tracking and the planner, whose head policy
(``--policy``: ``forward`` or ``sweep``) points the head. Scene ``i`` draws its world from
``default_rng([seed, i])`` and seeds the odometry's and the head's noise from it too.

The driver is the simulation's script, not the agent: a pure pursuit on the *true* pose
(from ``world_truth``) along the scene's path, with wheel commands at 20 Hz; it relays every
``odometry`` message as the ``vehicle_state`` (same stamp, pose, velocity and covariance,
frame ``odom``, no intent).

The vehicle passes through the movers, as it did before the simulator stopped it at
contact: the world stage, which integrates the vehicle's true motion and stops it for good
at the first contact, is given the static world only (the head, which sees the movers, and
the scoring get the whole world). The driver does not avoid movers (the closed loop's
controller does; :mod:`cli.closed_loop`), and a drive stopped for good by the first mover
across the path (9 of scenes 0-11, seed 0, most in the first 6 s) leaves a parked vehicle
watching for the rest of the minute. The path keeps clear of static obstacles; a contact
with one is still a collision, counted in ``drive.collisions`` (0 of 100 scenes, seed 0).

Scoring (:mod:`agent.scoring`; every definition is in the docstrings there):

* truth is compared in the drifting ``odom`` frame: a true point ``p`` is where a perfect
  tracker using this odometry would put it, ``T_odom(t)·T_true(t)⁻¹·p`` with both poses at
  the scan's stamp (:mod:`agent.scoring.frames`);
* ``gospa``: GOSPA (Rahmathullah, García-Fernández, Svensson 2017; c = 0.5 m, p = 1, α = 2,
  assignment by ``scipy.optimize.linear_sum_assignment``) per scan between the point objects
  (corners, cylinders, movers) that should be known (within 2.5 m of the centre of
  scanning, and hit by the samples of at least 3 scans: ever for static objects, in the
  last second for movers) and the confirmed corner and cylinder tracks (a track only
  matches an object of its kind; tracks paired with an object not expected, a pillar kept
  behind the vehicle, are left out); the mean over scans, and of its localisation, missed
  and false parts;
* ``position_rmse_m``: per kind, over the (track, object) pairs nearer than c with every
  true object (a track keeps the object it was paired with while within c, as in CLEAR
  MOT; the rest by the same assignment); segments by the distance of the track's midpoint
  from its face's line;
* ``nees``: ``static`` the (x, y) of corners and static cylinders (2 dof), ``moving`` the
  movers' (x, y, vx, vy) (4 dof), ``segment`` the segments' (α, ρ) (2 dof, apart from the
  points); each run's mean, then the mean over ``runs`` with its χ² 95 % interval;
* ``id_switches`` (a track changing object, or another id taking an object over),
  ``fragmentations`` (an object tracked under a new id after its track was deleted);
* ``static_deleted_out_of_view``: confirmed static tracks deleted while outside the scan's
  wedge (``static_deleted_in_view`` the others);
* ``false_tracks_per_scan``: confirmed tracks with no true object of their kind within c;
* ``confirm_latency_s``: movers, from the first scan whose samples hit it to the first scan
  with a confirmed track on it;
* ``false_free_rate``: over the bearings where the environment vector claims clear space,
  the fraction claiming more than 1 cm past the first true surface (static or mover, at the
  stamp, ray-cast from the true centre of scanning); ``free_coverage``: claimed over truly
  clear distance, both capped at 2.5 m (profiles taken while a mover overlapped the
  vehicle, which the scripted driver does not avoid, are counted,
  ``profiles_in_collision``, not scored);
* ``information``: the bits the tracks' updates brought (``½·log₂ det P⁻/det P⁺`` of each
  update's position, ``tracks/2``'s ``information_bits``) per second of driving, over all
  tracks (``bits_per_s``) and over those within ``path.object_m`` of the path ahead
  (``path_bits_per_s``): what the head's time buys, slews included
  (:mod:`agent.scoring.tracking`);
* ``per_scan_ms``: the tracking stage's ``handle()`` per features message
  (``time.perf_counter_ns``), p50 and p99, and ``tracks`` the mean number of tracks it holds.

``baseline``: Stone Soup's global nearest neighbour tracker (:mod:`cli.baseline_stonesoup`)
on the same point detections, scored by the same functions; skipped, with one line saying
so, when Stone Soup is not installed (``pip install .[baseline]``).
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from agent.arrays import FloatArray
from agent.runtime import topics
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import (
    EnvironmentVector,
    Features,
    FilteredScan,
    Header,
    Message,
    Odometry,
    Tracks,
    WheelCommand,
    WorldTruth,
    stamp_ns,
)
from agent.runtime.stage import Output, Params, Stage
from cli.bench_graph import vehicle_state_of
from cli.output import progress_bar, write_json

DEFAULT_SCENES = 8  # the command line's default: about two minutes with the baseline
MAX_SCENE_S = 60.0
DRIVE_RATE_HZ = 20.0
DRIVE_SPEED_M_S = 0.4
LOOKAHEAD_M = 0.6  # pure pursuit: about the turn radius the 60° path corners allow
MAX_YAW_RATE_RAD_S = 1.0
GOAL_TOLERANCE_M = 0.15
WORLD_RATE_HZ = 50.0  # truth and odometry: poses at a scan's stamp interpolate to < 1 mm
MOUNT_OFFSET_M = 0.30  # the nominal centre of scanning ahead of base_link
REACH_M = 2.5
INTENT_M = 3.0  # the driver's intent: its path this far ahead (the active planner's horizon)


# ----------------------------------------------------------------------------- the driver
class ScriptedDriver(Stage):
    """Drives the scene's path: pure pursuit on the true pose, wheel commands at 20 Hz.

    Inputs: ``world_truth`` (the true pose: this is the simulation's script, not the agent),
    ``odometry`` (relayed as ``vehicle_state``). Outputs: ``wheel_command`` every
    ``1/rate_hz`` s, ``vehicle_state`` for every odometry message.

    Parameters
    ----------
    path
        (k, 2) waypoints, world frame, metres; the vehicle starts at the first.
    speed_m_s
        Cruising speed (at most 0.4 m/s here); slower in sharp turns and near the end.
    """

    def __init__(
        self,
        path: FloatArray,
        speed_m_s: float = DRIVE_SPEED_M_S,
        rate_hz: float = DRIVE_RATE_HZ,
        lookahead_m: float = LOOKAHEAD_M,
    ) -> None:
        path = np.asarray(path, dtype=np.float64)
        if path.ndim != 2 or path.shape[1] != 2 or path.shape[0] < 2:
            raise ValueError(f"path must be (k >= 2, 2), got {path.shape}")
        self.path = path
        steps = np.hypot(*np.diff(path, axis=0).T)
        self.arc = np.concatenate([[0.0], np.cumsum(steps)])
        self.speed_m_s = speed_m_s
        self.period_s = 1.0 / rate_hz
        self.lookahead_m = lookahead_m
        self.pose: tuple[float, float, float] | None = None
        self.progress_m = 0.0
        self.progress_history: list[tuple[float, float]] = []  # (time s, progress m)
        self.done = False
        self._next: float | None = None
        self._counts = {"wheel_commands": 0, "vehicle_states": 0}

    def start(self, now_s: float) -> list[Output]:
        self._next = now_s
        return []

    def next_tick_s(self) -> float | None:
        return self._next

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic == topics.WORLD_TRUTH and isinstance(msg, WorldTruth):
            self.pose = (msg.x_m, msg.y_m, msg.yaw_rad)
        elif topic == topics.ODOMETRY and isinstance(msg, Odometry):
            self._counts["vehicle_states"] += 1
            return [(topics.VEHICLE_STATE, vehicle_state_of(msg, self.intent(msg)))]
        return []

    def path_ahead(self, progress_m: float) -> FloatArray:
        """(k, 2) world: the path's next ``INTENT_M`` from ``progress_m``, every 0.3 m."""
        s = progress_m + np.arange(0.3, INTENT_M + 1e-9, 0.3)
        s = s[s <= self.arc[-1]]
        return np.stack([np.interp(s, self.arc, self.path[:, i]) for i in (0, 1)], axis=1)

    def path_ahead_at(self, t_s: float) -> FloatArray:
        """:meth:`path_ahead` from the progress the driver had made at ``t_s``."""
        times = [t for t, _ in self.progress_history]
        k = int(np.searchsorted(times, t_s, side="right")) - 1
        return self.path_ahead(self.progress_history[k][1] if k >= 0 else 0.0)

    def intent(self, odometry: Odometry) -> FloatArray:
        """(k, 2) the path's next ``INTENT_M`` from the progress so far, every 0.3 m, mapped
        into ``odom`` by the odometry's and the truth's poses (what a controller following
        the path in ``odom`` would say it intends); empty before the truth's first pose."""
        if self.pose is None:
            return np.zeros((0, 2))
        world = self.path_ahead(self.progress_m)
        x, y, yaw = self.pose
        c, n = math.cos(yaw), math.sin(yaw)
        dx, dy = world[:, 0] - x, world[:, 1] - y
        local = np.stack([c * dx + n * dy, -n * dx + c * dy], axis=1)  # base_link
        co, so = math.cos(odometry.yaw_rad), math.sin(odometry.yaw_rad)
        return np.stack([
            odometry.x_m + co * local[:, 0] - so * local[:, 1],
            odometry.y_m + so * local[:, 0] + co * local[:, 1],
        ], axis=1)  # fmt: skip

    def _progress(self, xy: FloatArray) -> float:
        """Arc length of the path point nearest ``xy``, not behind the progress so far."""
        a, b = self.path[:-1], self.path[1:]
        d = b - a
        u = np.clip(np.einsum("ij,ij->i", xy - a, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
        gap = np.hypot(*(a + u[:, None] * d - xy).T)
        along = self.arc[:-1] + u * np.diff(self.arc)
        ahead = along >= self.progress_m - 0.5  # never jump back to an earlier leg
        best = int(np.argmin(np.where(ahead, gap, np.inf)))
        return max(self.progress_m, float(along[best]))

    def _point_at(self, s: float) -> FloatArray:
        s = min(max(s, 0.0), float(self.arc[-1]))
        return np.array([np.interp(s, self.arc, self.path[:, i]) for i in (0, 1)])

    def command(self) -> tuple[float, float]:
        """(speed m/s, yaw rate rad/s) toward the path's look-ahead point."""
        if self.pose is None or self.done:
            return 0.0, 0.0
        x, y, yaw = self.pose
        xy = np.array([x, y])
        self.progress_m = self._progress(xy)
        to_end = float(np.hypot(*(self.path[-1] - xy)))
        if self.arc[-1] - self.progress_m < 0.5 * self.lookahead_m and to_end < GOAL_TOLERANCE_M:
            self.done = True
            return 0.0, 0.0
        target = self._point_at(self.progress_m + self.lookahead_m)
        if self.arc[-1] - self.progress_m < self.lookahead_m:
            target = self.path[-1]
        alpha = math.remainder(math.atan2(target[1] - y, target[0] - x) - yaw, math.tau)
        distance = max(float(np.hypot(*(target - xy))), 1e-6)
        speed = self.speed_m_s * max(0.1, math.cos(alpha)) if abs(alpha) < math.pi / 2 else 0.0
        speed = min(speed, max(0.05, to_end))  # slow down over the last metres
        yaw_rate = 2.0 * math.sin(alpha) / distance * max(speed, 0.1)
        if speed == 0.0:
            yaw_rate = math.copysign(MAX_YAW_RATE_RAD_S, alpha)
        return speed, min(max(yaw_rate, -MAX_YAW_RATE_RAD_S), MAX_YAW_RATE_RAD_S)

    def tick(self, now_s: float) -> list[Output]:
        self._next = (self._next if self._next is not None else now_s) + self.period_s
        speed, yaw_rate = self.command()
        self.progress_history.append((now_s, self.progress_m))
        self._counts["wheel_commands"] += 1
        cmd = WheelCommand(
            header=Header(stamp_ns=stamp_ns(now_s), frame_id="base_link"),
            speed_m_s=speed,
            yaw_rate_rad_s=yaw_rate,
        )
        return [(topics.WHEEL_COMMAND, cmd)]

    def counters(self) -> dict[str, int]:
        return dict(self._counts)


class TimedStage(Stage):
    """Passes everything to ``stage``; times its ``handle()`` of ``topic`` messages and
    notes how many tracks each such call published (0 if none)."""

    def __init__(self, stage: Stage, topic: str) -> None:
        self.stage = stage
        self.topic = topic
        self.handle_ns: list[int] = []
        self.tracks_after: list[int] = []

    def prepare(self) -> None:
        self.stage.prepare()

    def start(self, now_s: float) -> list[Output]:
        return self.stage.start(now_s)

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        if topic != self.topic:
            return self.stage.handle(topic, msg, now_s)
        started = time.perf_counter_ns()
        out = self.stage.handle(topic, msg, now_s)
        self.handle_ns.append(time.perf_counter_ns() - started)
        self.tracks_after.append(
            sum(int(m.track_id.shape[0]) for _, m in out if isinstance(m, Tracks))
        )
        return out

    def tick(self, now_s: float) -> list[Output]:
        return self.stage.tick(now_s)

    def next_tick_s(self) -> float | None:
        return self.stage.next_tick_s()

    def counters(self) -> dict[str, int]:
        return self.stage.counters()


# ------------------------------------------------------------------------------ a scene
@dataclass
class _Pending:
    """Messages waiting for the truth and odometry to cover their stamp."""

    tracks: list[Tracks] = field(default_factory=list)
    environments: list[EnvironmentVector] = field(default_factory=list)
    features: list[Features] = field(default_factory=list)


@dataclass
class Tally:
    """Everything the scenes add up."""

    ours: Any
    baseline: Any | None
    free: Any
    handle_ns: list[int] = field(default_factory=list)
    handle_tracks: list[int] = field(default_factory=list)
    track_counts: list[int] = field(default_factory=list)
    baseline_ns: list[int] = field(default_factory=list)
    baseline_track_counts: list[int] = field(default_factory=list)
    scans: int = 0
    drive_s: list[float] = field(default_factory=list)
    distance_m: list[float] = field(default_factory=list)
    movers: int = 0
    collisions: int = 0
    counters: dict[str, int] = field(default_factory=dict)


def _track_view(msg: Tracks) -> Any:
    from agent.scoring.tracking import TrackView

    return TrackView(
        track_id=msg.track_id, kind=msg.kind, confirmed=msg.status >= 1, state=msg.state,
        covariance=msg.covariance, params=msg.params,
        params_covariance=msg.params_covariance, extent=msg.extent,
        moving_probability=msg.moving_probability,
        updated=msg.last_seen_ns == msg.header.stamp_ns,
        information_bits=(
            msg.information_bits if msg.information_bits.shape == msg.track_id.shape else None
        ),
    )  # fmt: skip


def run_scene(
    index: int,
    seed: int,
    policy: str,
    tally: Tally,
    max_s: float,
    record: dict[str, Any] | None = None,
) -> None:
    """One scene: build, drive, score (module docstring). With ``record``, what the run plot
    needs is kept there (:func:`plot_run`)."""
    from agent.scoring.frames import PoseHistory
    from agent.scoring.free_space import score_profile
    from agent.scoring.tracking import ScanInput, TrackView
    from agent.scoring.truth import scene_truth
    from agent.sim.movers import mover_states
    from agent.sim.worldgen import tracking_scene
    from agent.stages.tracking_stage import TrackingStage
    from agent.stages.world_stage import WorldStage
    from cli.closed_loop import agent_nodes

    rng = np.random.default_rng([seed, index])
    world, path = tracking_scene(rng)
    noise_seeds = rng.integers(0, 2**31, 2).tolist()
    driver = ScriptedDriver(path)
    # The movers are the head's (it sees them) but not the vehicle's (module docstring).
    world_stage = WorldStage(replace(world, movers=()), rate_hz=WORLD_RATE_HZ, seed=noise_seeds[0])
    tracking = TimedStage(TrackingStage.from_params(Params("tracking", {})), topics.FEATURES)
    nodes = [
        Node("world", world_stage, (topics.WHEEL_COMMAND,)),
        Node("driver", driver, (topics.WORLD_TRUTH, topics.ODOMETRY)),
        *agent_nodes(world, policy, noise_seeds[1], tracking),
    ]  # fmt: skip
    runner = LockstepRunner(nodes)
    truth = scene_truth(world)
    radius = np.array([m.radius_m for m in world.movers], dtype=np.float64)
    tally.ours.start_run(truth, world.n_movers)
    baseline = None
    if tally.baseline is not None:
        from cli.baseline_stonesoup import StoneSoupBaseline, detections_in_odom

        baseline = StoneSoupBaseline()
        tally.baseline.start_run(truth, world.n_movers)
    tally.movers += world.n_movers
    true_poses, odom_poses = PoseHistory(), PoseHistory()
    scans: dict[int, FilteredScan] = {}
    pending = _Pending()
    last = {"distance_m": 0.0}

    def scan_input(stamp: int) -> ScanInput | None:
        t = stamp * 1e-9
        true_pose, odom_pose = true_poses.at(t), odom_poses.at(t)
        scan = scans.get(stamp)
        if true_pose is None or odom_pose is None or scan is None:
            return None
        valid = (scan.flag == 0) & np.isfinite(scan.points_xy).all(axis=1)
        origin = scan.origin_xy[valid].mean(axis=0) if valid.any() else np.array([0.3, 0.0])
        mover_xy, mover_v = mover_states(world.movers, t)
        return ScanInput(
            stamp_s=t, true_pose=true_pose, odom_pose=odom_pose,
            points_base=scan.points_xy[valid], sigma_m=scan.sigma_m[valid],
            origin_base=origin, mover_xy=mover_xy.reshape(-1, 2),
            mover_velocity_xy=mover_v.reshape(-1, 2), mover_radius_m=radius,
            path_ahead_xy=driver.path_ahead_at(t),
        )  # fmt: skip

    def settle(final: bool = False) -> None:
        """Score what the truth now covers (all of it at the end: the rest is dropped)."""
        horizon = min(true_poses.last_s, odom_poses.last_s)
        for msg in [m for m in pending.features if m.header.stamp_s <= horizon]:
            pending.features.remove(msg)
            pose = odom_poses.at(msg.header.stamp_s)
            if baseline is None or tally.baseline is None or pose is None:
                continue
            kind, xy, cov = detections_in_odom(msg.kind, msg.params, msg.covariance, pose)
            started = time.perf_counter_ns()
            ids, kinds, state, covariance = baseline.step(msg.header.stamp_s, kind, xy, cov)
            tally.baseline_ns.append(time.perf_counter_ns() - started)
            tally.baseline_track_counts.append(int(ids.size))
            scan = scan_input(msg.header.stamp_ns)
            if scan is not None:
                tally.baseline.add_scan(scan, TrackView.points(ids, kinds, state, covariance))
        for tracks_msg in [m for m in pending.tracks if m.header.stamp_s <= horizon]:
            pending.tracks.remove(tracks_msg)
            scan = scan_input(tracks_msg.header.stamp_ns)
            if scan is not None:
                tally.ours.add_scan(scan, _track_view(tracks_msg))
                tally.scans += 1
        for env in [m for m in pending.environments if m.header.stamp_s <= horizon]:
            pending.environments.remove(env)
            t = env.header.stamp_s
            true_pose = true_poses.at(t)
            if true_pose is None or env.free_bearing_rad.size == 0:
                continue
            mover_xy, _ = mover_states(world.movers, t)
            score_profile(
                tally.free, world, mover_xy.reshape(-1, 2), radius, true_pose,
                env.free_bearing_rad, env.free_range_m, MOUNT_OFFSET_M, REACH_M,
            )  # fmt: skip
        if final:
            pending.features.clear()
            pending.tracks.clear()
            pending.environments.clear()

    if record is not None:
        record.update(world=world, true_xy=[], mover_xy=[], snapshots=[], next_snapshot_s=0.0)

    def keep(msg: Message) -> None:
        """The run plot's share of ``msg`` (``record`` given)."""
        assert record is not None
        if isinstance(msg, WorldTruth):
            record["true_xy"].append((msg.x_m, msg.y_m))
            record["mover_xy"].append(msg.mover_xy)
        elif isinstance(msg, EnvironmentVector) and msg.header.stamp_s >= record["next_snapshot_s"]:
            t = msg.header.stamp_s
            true_pose, odom_pose = true_poses.at(t), odom_poses.at(t)
            if true_pose is None or odom_pose is None:
                return
            record["next_snapshot_s"] = t + SNAPSHOT_EVERY_S
            record["snapshots"].append(_snapshot(msg, true_pose, odom_pose))

    def seen(_t: float, topic: str, msg: Message) -> None:
        if record is not None:
            keep(msg)
        if isinstance(msg, WorldTruth):
            true_poses.add(msg.header.stamp_s, msg.x_m, msg.y_m, msg.yaw_rad)
            settle()
        elif isinstance(msg, Odometry):
            odom_poses.add(msg.header.stamp_s, msg.x_m, msg.y_m, msg.yaw_rad)
            last["distance_m"] = msg.distance_m
        elif isinstance(msg, FilteredScan):
            scans[msg.header.stamp_ns] = msg
            for old in [s for s in scans if s < msg.header.stamp_ns - 2_000_000_000]:
                del scans[old]  # two seconds of scans cover every message still pending
        elif isinstance(msg, Features):
            pending.features.append(msg)
        elif isinstance(msg, Tracks):
            tally.track_counts.append(int(msg.track_id.shape[0]))
            pending.tracks.append(msg)
        elif isinstance(msg, EnvironmentVector) and msg.sensor_ok:
            pending.environments.append(msg)

    runner.observe(seen)
    t = 0.0
    while t < max_s and not driver.done:
        t = min(max_s, t + 0.5)
        runner.run_until(t)
    runner.run_until(t + 0.3)  # the last scans through the graph, the truth past them
    settle(final=True)
    tally.ours.end_run()
    if tally.baseline is not None:
        tally.baseline.end_run()
    tally.handle_ns.extend(tracking.handle_ns)
    tally.handle_tracks.extend(tracking.tracks_after)
    tally.drive_s.append(t)
    tally.distance_m.append(last["distance_m"])
    tally.collisions += bool(world_stage.collision)
    for node in nodes:
        for name, value in node.stage.counters().items():
            key = f"{node.name}.{name}"
            tally.counters[key] = tally.counters.get(key, 0) + int(value)


SNAPSHOT_EVERY_S = 5.0  # the run plot draws an environment vector this often


def _snapshot(msg: EnvironmentVector, true_pose: FloatArray, odom_pose: FloatArray) -> Any:
    """``msg`` in the world frame, through the odometry's error at its stamp: a point the
    agent puts at ``p`` in odom is, relative to the true vehicle, where it believes it to be
    relative to its odometry pose (T_world←odom = T_true · T_odom⁻¹)."""
    from cli.plots import EnvironmentSnapshot

    dyaw = float(true_pose[2] - odom_pose[2])
    c, s = math.cos(dyaw), math.sin(dyaw)
    rot = np.array([[c, -s], [s, c]])
    to_world = lambda p: (p - odom_pose[:2]) @ rot.T + true_pose[:2]  # noqa: E731
    cy, sy = math.cos(true_pose[2]), math.sin(true_pose[2])
    centre = true_pose[:2] + MOUNT_OFFSET_M * np.array([cy, sy])
    trusted = msg.kind != 2  # edges are not obstacles of their own
    return EnvironmentSnapshot(
        t_s=msg.header.stamp_s, centre_xy=centre, bearing_rad=msg.free_bearing_rad + true_pose[2],
        free_m=msg.free_range_m, obstacle_xy=to_world(msg.position_xy[trusted]),
        obstacle_cov=rot @ msg.covariance[trusted][:, :2, :2] @ rot.T,
        obstacle_kind=msg.kind[trusted].astype(np.float64),
    )  # fmt: skip


def plot_run(seed: int, policy: str, path: Path, max_s: float = MAX_SCENE_S) -> Path:
    """Drive the benchmark's first scene and draw it (:func:`cli.plots.environment_over_run`)."""
    from agent.scoring.free_space import FreeSpaceScore
    from agent.scoring.tracking import TrackingScore
    from cli.plots import environment_over_run

    record: dict[str, Any] = {}
    tally = Tally(ours=TrackingScore(), baseline=None, free=FreeSpaceScore())
    run_scene(0, seed, policy, tally, max_s, record)
    world = record["world"]
    movers = np.asarray(record["mover_xy"], dtype=np.float64)  # (t, m, 2)
    return environment_over_run(
        (world.segments_start, world.segments_end),
        (world.circles_center, world.circles_radius),
        np.asarray(record["true_xy"], dtype=np.float64),
        [movers[:, i] for i in range(movers.shape[1])] if movers.ndim == 3 else [],
        record["snapshots"],
        path,
        f"scene 0 of seed {seed}, policy {policy}: the environment vector every "
        f"{SNAPSHOT_EVERY_S:g} s,\nmapped into the world through the odometry's error",
    )


# ------------------------------------------------------------------------------ figures
TRACK_BINS = (0, 5, 10, 20, 40)  # per_scan_ms by the number of tracks held after the scan


def _ms_by_tracks(ns: list[int], tracks: list[int]) -> dict[str, Any]:
    """p50 and p99 ms per bin of ``TRACK_BINS`` (scans in each as ``scans``)."""
    t = np.asarray(tracks)
    ms = np.asarray(ns, dtype=np.float64) * 1e-6
    out: dict[str, Any] = {}
    edges = [*TRACK_BINS, 10**9]
    for lo, hi in itertools.pairwise(edges):
        mine = ms[(t >= lo) & (t < hi)]
        name = f"{lo}-{hi - 1}" if hi < 10**9 else f"{lo}+"
        out[name] = {
            "scans": int(mine.size),
            "p50": float(np.percentile(mine, 50)) if mine.size else None,
            "p99": float(np.percentile(mine, 99)) if mine.size else None,
        }
    return out


def _ms(ns: list[int]) -> dict[str, float | None]:
    if not ns:
        return {"p50": None, "p99": None}
    ms = np.asarray(ns, dtype=np.float64) * 1e-6
    return {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99))}


def baseline_available() -> str | None:
    """None when Stone Soup can be imported, else why not (one line)."""
    try:
        import cli.baseline_stonesoup  # noqa: F401
    except ImportError as exc:
        return f"Stone Soup not installed ({exc}); baseline skipped (pip install '.[baseline]')"
    return None


def tracking_figures(
    scenes: int,
    seed: int,
    policy: str,
    baseline: bool = True,
    max_scene_s: float = MAX_SCENE_S,
    progress: Any = None,
) -> dict[str, Any]:
    """Run ``scenes`` scenes and return every figure (module docstring)."""
    from agent import perception, tracking
    from agent.scoring.free_space import FreeSpaceScore
    from agent.scoring.tracking import TrackingScore
    from agent.sim import raycast

    perception.warm_up()  # compiled loops loaded before any timing
    tracking.warm_up()
    raycast.warm_up()
    tally = Tally(
        ours=TrackingScore(),
        baseline=TrackingScore() if baseline else None,
        free=FreeSpaceScore(),
    )
    for i in range(scenes):
        run_scene(i, seed, policy, tally, max_scene_s)
        if progress is not None:
            progress(i + 1, scenes)
    ours = tally.ours.summary()
    figures: dict[str, Any] = {
        "scenes": scenes,
        "scans": tally.scans,
        "seed": seed,
        "policy": policy,
        **ours,
        "false_free_rate": tally.free.false_free_rate,
        "free_coverage": tally.free.coverage,
        "free_space": {
            "profiles": tally.free.profiles,
            "bearings_claimed": tally.free.claimed,
            "bearings_false": tally.free.false,
            "bearings_false_at_mover": tally.free.false_at_mover,
            "profiles_in_collision": tally.free.in_collision,
            "tolerance_m": 0.01,
        },
        "per_scan_ms": {
            **_ms(tally.handle_ns),
            "tracks": float(np.mean(tally.track_counts)) if tally.track_counts else None,
            "max_tracks": int(max(tally.track_counts)) if tally.track_counts else None,
            "by_tracks_held": _ms_by_tracks(tally.handle_ns, tally.handle_tracks),
        },
        "drive": {
            "seconds": float(np.sum(tally.drive_s)),
            "odometry_distance_m": float(np.sum(tally.distance_m)),
            "movers": tally.movers,
            "collisions": tally.collisions,
        },
        "counters": tally.counters,
    }
    if tally.baseline is not None:
        from cli.baseline_stonesoup import NAME, StoneSoupBaseline

        b = tally.baseline.summary()
        figures["baseline"] = {
            "name": NAME,
            "settings": StoneSoupBaseline().settings,
            "gospa": b["gospa"],
            "position_rmse_m": b["position_rmse_m"],
            "nees": b["nees"],
            "id_switches": b["id_switches"],
            "fragmentations": b["fragmentations"],
            "false_tracks_per_scan": b["false_tracks_per_scan"],
            "confirm_latency_s": b["confirm_latency_s"],
            "per_scan_ms": {
                **_ms(tally.baseline_ns),
                "tracks": (
                    float(np.mean(tally.baseline_track_counts))
                    if tally.baseline_track_counts
                    else None
                ),
                "by_tracks_held": _ms_by_tracks(tally.baseline_ns, tally.baseline_track_counts),
            },
        }
    else:
        figures["baseline"] = None
    return figures


def _show(value: Any, fmt: str) -> str:
    return "n/a" if value is None else format(value, fmt)


def print_table(f: dict[str, Any]) -> None:
    b = f["baseline"] or {}
    d = f["drive"]
    print(
        f"tracking over {f['scenes']} scenes, {f['scans']} scans ({d['seconds']:.0f} s driven, "
        f"{d['odometry_distance_m']:.1f} m, {d['movers']} movers, "
        f"{d['collisions']} collisions), policy {f['policy']}, "
        f"seed {f['seed']}"
    )
    print(f"  {'':34s} {'agent':>10s} {'baseline':>10s}")

    def row(label: str, get: Any, fmt: str) -> None:
        mine = _show(get(f), fmt)
        theirs = _show(get(b), fmt) if b else "-"
        print(f"  {label:34s} {mine:>10s} {theirs:>10s}")

    def dig(*keys: str) -> Any:
        def get(d: dict[str, Any]) -> Any:
            for k in keys:
                if not isinstance(d, dict) or k not in d:
                    return None
                d = d[k]
            return d

        return get

    row("GOSPA mean (m, c 0.5, p 1)", dig("gospa", "mean"), ".3f")
    row("  localisation", dig("gospa", "localisation"), ".3f")
    row("  missed", dig("gospa", "missed"), ".3f")
    row("  false", dig("gospa", "false"), ".3f")
    for kind in ("segment", "corner", "cylinder", "mover"):
        row(f"position RMSE {kind} (m)", dig("position_rmse_m", kind), ".3f")
    for kind, dof in (("static", 2), ("moving", 4), ("segment", 2)):
        row(f"NEES {kind} ({dof} dof), mean of runs", dig("nees", kind, "mean"), ".2f")
    row("id switches", dig("id_switches"), "d")
    row("fragmentations", dig("fragmentations"), "d")
    row("static deleted out of view", dig("static_deleted_out_of_view"), "d")
    row("false tracks per scan", dig("false_tracks_per_scan"), ".3f")
    row("mover confirm latency p50 (s)", dig("confirm_latency_s", "p50"), ".2f")
    row("mover confirm latency p95 (s)", dig("confirm_latency_s", "p95"), ".2f")
    row("  near the path: p50 (s)", dig("path", "confirm_latency_s", "p50"), ".2f")
    row("  near the path: p95 (s)", dig("path", "confirm_latency_s", "p95"), ".2f")
    row("path objects' track σ (m)", dig("path", "track_sigma_m_mean"), ".4f")
    row("path objects tracked", dig("path", "objects_tracked"), ".3f")
    row("information (bit/s), all tracks", dig("information", "bits_per_s"), ".2f")
    row("  near the path (bit/s)", dig("information", "path_bits_per_s"), ".2f")
    row("per scan p50 (ms)", dig("per_scan_ms", "p50"), ".3f")
    row("per scan p99 (ms)", dig("per_scan_ms", "p99"), ".3f")
    row("tracks held (mean)", dig("per_scan_ms", "tracks"), ".1f")
    row("false free rate", dig("false_free_rate"), ".3%")
    row("free coverage", dig("free_coverage"), ".1%")
    for kind in ("static", "moving", "segment"):
        n = f["nees"][kind]
        if n["interval_95"] is not None:
            lo, hi = n["interval_95"]
            print(f"  NEES {kind}: {n['runs']} runs, {n['samples']} samples, "
                  f"χ² 95 % interval for that many runs [{lo:.2f}, {hi:.2f}]")  # fmt: skip
            parts = [f"{p} {n[p]['mean']:.2f} ({n[p]['samples']})"
                     for p in ("updated", "coasting") if n[p]["mean"] is not None]  # fmt: skip
            w = n["within_999"]
            print(f"    samples' mean when {', '.join(parts)}; mean of runs within "
                  f"χ² 99.9 % {_show(w['mean'], '.2f')}, "
                  f"{_show(w['beyond_share'], '.1%')} beyond")  # fmt: skip
    if b and f["gospa"]["mean"] is not None and b["gospa"]["mean"]:
        gain = 1.0 - f["gospa"]["mean"] / b["gospa"]["mean"]
        ratio = [
            (b["per_scan_ms"][q] or 0.0) / (f["per_scan_ms"][q] or math.inf) for q in ("p50", "p99")
        ]
        print(
            f"  the agent's mean GOSPA is {abs(gain):.0%} {'below' if gain >= 0 else 'above'} "
            f"the baseline's; per scan the baseline takes {ratio[0]:.2g}x the agent's time "
            f"at p50, {ratio[1]:.2g}x at p99"
        )
    for name, mine in f["per_scan_ms"]["by_tracks_held"].items():
        theirs = b["per_scan_ms"]["by_tracks_held"][name] if b else {"scans": 0, "p50": None}
        if mine["scans"] or theirs["scans"]:
            print(
                f"  per scan with {name} tracks held: agent p50 {_show(mine['p50'], '.3f')} ms "
                f"({mine['scans']} scans), baseline p50 {_show(theirs['p50'], '.3f')} ms "
                f"({theirs['scans']} scans)"
            )


def tracking_command(args: argparse.Namespace) -> int:
    """``sensor-agent bench tracking``."""
    if args.scenes < 1:
        print("sensor-agent: --scenes must be at least 1", file=sys.stderr)
        return 2
    if args.max_scene_s is not None and not args.max_scene_s > 0:
        print("sensor-agent: --max-scene-s must be positive", file=sys.stderr)
        return 2
    why = baseline_available() if not args.no_baseline else "baseline skipped (--no-baseline)"
    if why is not None:
        print(why)
    with progress_bar("tracking scenes") as progress:
        figures = tracking_figures(
            args.scenes,
            args.seed,
            args.policy,
            baseline=why is None,
            max_scene_s=args.max_scene_s or MAX_SCENE_S,
            progress=progress,
        )
    print_table(figures)
    if args.json is not None:
        write_json(Path(args.json), figures)
    if args.plot is not None:
        print(f"wrote {plot_run(args.seed, args.policy, Path(args.plot))}")
    return 0
