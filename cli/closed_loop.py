"""One world's task driven in lock-step, start to outcome: the closed loop of ``demo
--lockstep`` and ``evaluate``.

The graph is ``launch/demo.toml``'s, stage for stage: the world simulator (true motion,
collisions, odometry), the simulated head, calibration, filtering, features, tracking, the
planner (the head policy and the environment vector) and the vehicle controller, on one
simulated clock (:class:`agent.runtime.lockstep.LockstepRunner`). The controller reads only
``odometry`` and ``environment``; truth is read here, for scoring, and nowhere else.

A run ends at the first of: a collision (the world stage stops the vehicle for good), the
controller reporting it has arrived (and stopped), or the task's time limit. Its outcome:

* ``success``: arrived, and the true pose meets the task
  (:func:`agent.scoring.closed_loop.task_success`);
* ``collision``: the outline touched an obstacle or a mover (``collision_by`` says who moved);
* ``stale_stop``: the time ran out while the controller held the vehicle for want of a valid
  environment vector (stale or untrusted) for the last :data:`STALE_STOP_S` seconds or more;
* ``timeout``: otherwise (the time ran out, or the controller stopped somewhere the truth
  does not accept: ``arrived_wrong`` is then true).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agent.kinematics.vehicle import VehicleSpec
from agent.runtime import topics
from agent.runtime.lockstep import LockstepRunner, Node
from agent.runtime.messages import Message, Odometry, WorldTruth
from agent.runtime.stage import Params, Stage
from agent.sim.odometry import OdometryErrorModel
from agent.sim.world import World
from agent.task import Task
from cli.evaluate import POLICIES

WORLD_RATE_HZ = 20.0  # as launch/demo.toml
CHUNK_S = 0.25  # the runner advances this far between checks of the outcome
STALE_STOP_S = 5.0  # held for want of a valid vector at least this long at the end: stale_stop
SETTLE_S = 0.3  # after the controller reports arrival, before the pose is judged
VEHICLE = VehicleSpec()
STOPPED_REASONS = ("stale_environment", "sensor_not_ok", "no_environment")
KNOWN_AHEAD_EVERY_S = 0.5  # how often the controller's known space is sampled
KNOWN_AHEAD_S = 2.0  # ... against the space the vehicle's outline sweeps this long after
KNOWN_AHEAD_MIN_M = 0.2  # samples after which the vehicle moves less than this are left out
KNOWN_WAY_M = 1.0  # how far along its way the vehicle's knowledge is followed (known_way_m)
_KEY_BASE, _KEY_OFFSET = 1 << 20, 1 << 19  # a cell (row, column) as one integer (any grid)

Observer = Callable[[float, str, Message], None]


@dataclass
class LoopResult:
    """What one closed-loop run did (truth included: this is for scoring)."""

    outcome: str
    collision_by: str | None
    collision_with: str | None  # "static" or "mover": what the outline touched
    time_s: float
    min_clearance_m: float
    arrived: bool
    arrived_wrong: bool
    true_path: np.ndarray  # (k, 2) world frame, at WORLD_RATE_HZ
    final_pose: tuple[float, float, float]  # true x, y, yaw (rad)
    stopped_stale_s: float  # the time held for want of a valid vector, in all
    wall_s: float
    counters: dict[str, int] = field(default_factory=dict)
    decision_us: list[int] = field(default_factory=list)  # the head planner's, wall clock
    path_known_ahead: float | None = None  # known_ahead(): the mean over its samples
    known_way_m: float | None = None  # known_way(): the mean over its samples
    standing_s: dict[str, float] = field(default_factory=dict)  # standing, by the reason


def agent_nodes(world: World, policy: str, head_seed: int, tracking: Any = None) -> list[Node]:
    """The simulated head and the agent's stages (calibration, filtering, features,
    tracking, the planner with head ``policy``), as launch/demo.toml wires them; ``tracking``
    replaces the tracking stage (a bench's timed wrapper)."""
    from agent.stages.calibration_stage import CalibrationStage
    from agent.stages.features_stage import FeaturesStage
    from agent.stages.filtering_stage import FilteringStage
    from agent.stages.head_stage import HeadStage
    from agent.stages.planner_stage import PlannerStage
    from agent.stages.tracking_stage import TrackingStage

    if tracking is None:
        tracking = TrackingStage.from_params(Params("tracking", {}))
    return [
        Node("head", HeadStage(world, seed=head_seed), (topics.HEAD_COMMAND, topics.WORLD_TRUTH)),
        Node("calibration", CalibrationStage.from_params(Params("calibration", {})),
             (topics.RAW_SCAN,)),
        Node("filtering", FilteringStage.from_params(Params("filtering", {})),
             (topics.CALIBRATED_SCAN, topics.VEHICLE_STATE)),
        Node("features", FeaturesStage.from_params(Params("features", {})),
             (topics.FILTERED_SCAN,)),
        Node("tracking", tracking, (topics.FEATURES, topics.VEHICLE_STATE, topics.FILTERED_SCAN)),
        Node("planner", PlannerStage.from_params(Params("planner", {"policy": policy})),
             (topics.TRACKS, topics.FILTERED_SCAN, topics.VEHICLE_STATE, topics.HEAD_STATE)),
    ]  # fmt: skip


def closed_loop_nodes(
    world: World,
    task: Task,
    policy: str,
    planner: str,
    seed: int,
    odometry: OdometryErrorModel | None = None,
) -> tuple[list[Node], Any, Any]:
    """The graph's stages for ``world`` (launch/demo.toml's, built in code) and, for the
    caller's checks, the world and vehicle stages. ``seed`` draws the odometry's errors and
    the head's noise; ``odometry`` replaces the odometry's error model (the default's
    spreads when ``None``)."""
    from agent.stages.vehicle_stage import VehicleStage
    from agent.stages.world_stage import WorldStage

    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
    noise = np.random.default_rng([seed, 7]).integers(0, 2**31, 2).tolist()
    world_stage = WorldStage(world, rate_hz=WORLD_RATE_HZ, seed=noise[0], odometry=odometry)
    vehicle = VehicleStage(task, planner="dwa" if planner == "dwa" else "default")
    nodes = [
        Node("world", world_stage, (topics.WHEEL_COMMAND,)),
        *agent_nodes(world, policy, noise[1]),
        Node("vehicle", vehicle, (topics.ODOMETRY, topics.ENVIRONMENT)),
    ]
    return nodes, world_stage, vehicle


def run_closed_loop(
    world: World,
    task: Task,
    policy: str = "forward",
    planner: str = "default",
    seed: int = 0,
    observe: Observer | None = None,
    serialise: bool = False,
    progress: Callable[[float, str], None] | None = None,
    wrap_stage: Callable[[str, Stage], Stage] | None = None,
    odometry: OdometryErrorModel | None = None,
) -> LoopResult:
    """Drive ``task`` in ``world`` to its outcome (module docstring).

    ``observe`` sees every message the graph passes (a plot's or a recording's share);
    ``serialise`` sends each through its wire encoding, as between processes (slower, the
    same answers); ``progress`` is called after every chunk with the time and the
    controller's mode; ``wrap_stage(name, stage)`` replaces each node's stage (a bench's
    timed wrapper, which calls the stage it wraps); ``odometry`` replaces the odometry's
    error model (a diagnostic's perfect odometry).
    """
    from agent.scoring.closed_loop import task_success

    nodes, world_stage, vehicle = closed_loop_nodes(
        world, task, policy, planner, seed, odometry=odometry
    )
    if wrap_stage is not None:
        for node in nodes:
            node.stage = wrap_stage(node.name, node.stage)
    runner = LockstepRunner(nodes, serialise=serialise)
    true_xy: list[tuple[float, float]] = []
    decision_us = _time_decisions(nodes)

    odometry_poses: list[tuple[float, float, float, float]] = []  # (t, x, y, yaw) as published
    known: list[tuple[float, np.ndarray, float, np.ndarray]] = []

    def seen(t: float, topic: str, msg: Message) -> None:
        if isinstance(msg, WorldTruth):
            true_xy.append((msg.x_m, msg.y_m))
        elif isinstance(msg, Odometry):
            odometry_poses.append((msg.header.stamp_s, msg.x_m, msg.y_m, msg.yaw_rad))
        if observe is not None:
            observe(t, topic, msg)

    runner.observe(seen)
    started = time.perf_counter()
    t = 0.0
    stopped_stale_s = held_s = 0.0
    standing_s: dict[str, float] = {}  # the command zero, by the controller's reason
    arrived_at: float | None = None
    while t < task.time_limit_s:
        t = min(task.time_limit_s, t + CHUNK_S)
        runner.run_until(t)
        local = vehicle.controller._local
        if local is not None and (not known or t - known[-1][0] >= KNOWN_AHEAD_EVERY_S - 1e-9):
            known.append((t, local.origin_xy.copy(), local.cell_m, local.state.copy()))
        last = vehicle.last
        if (
            last is not None and arrived_at is None  # (not the settling once arrived)
            and last.speed_m_s == 0.0 and last.yaw_rate_rad_s == 0.0
        ):  # fmt: skip
            reason = last.reason or "-"
            standing_s[reason] = standing_s.get(reason, 0.0) + CHUNK_S
        if last is not None and last.speed_m_s == 0.0 and last.reason in STOPPED_REASONS:
            stopped_stale_s += CHUNK_S
            held_s += CHUNK_S
        else:
            held_s = 0.0
        if progress is not None:
            progress(t, "" if last is None else last.mode)
        if world_stage.collision:
            break
        if last is not None and last.arrived:
            if arrived_at is None:
                arrived_at = t
            elif t - arrived_at >= SETTLE_S:
                break
        else:
            arrived_at = None
    wall = time.perf_counter() - started
    pose = (world_stage.x, world_stage.y, world_stage.yaw)
    arrived = arrived_at is not None
    collision_by: str | None = None
    collision_with: str | None = None
    if world_stage.collision:
        outcome, collision_by = "collision", str(world_stage.collision)
        is_mover = world_stage.collision_obstacle >= world.mover_id_base
        collision_with = "mover" if is_mover else "static"
        time_s = float(world_stage.collision_time_s)
    elif arrived and task_success(task, pose, world=world):
        outcome, time_s = "success", float(arrived_at)  # type: ignore[arg-type]
    elif held_s >= STALE_STOP_S:
        outcome, time_s = "stale_stop", t
    else:
        outcome, time_s = "timeout", t
    counters: dict[str, int] = {}
    for node in nodes:
        for name, value in node.stage.counters().items():
            counters[f"{node.name}.{name}"] = int(value)
    return LoopResult(
        outcome=outcome, collision_by=collision_by, collision_with=collision_with,
        time_s=time_s, min_clearance_m=float(world_stage.min_clearance_m), arrived=arrived,
        arrived_wrong=arrived and outcome != "success" and outcome != "collision",
        true_path=np.asarray(true_xy, dtype=np.float64).reshape(-1, 2),
        final_pose=(float(pose[0]), float(pose[1]), float(pose[2])),
        stopped_stale_s=stopped_stale_s, wall_s=wall, counters=counters,
        decision_us=decision_us, path_known_ahead=known_ahead(known, odometry_poses),
        known_way_m=known_way(known, odometry_poses), standing_s=standing_s,
    )  # fmt: skip


def known_ahead(
    samples: list[tuple[float, np.ndarray, float, np.ndarray]],
    odometry: list[tuple[float, float, float, float]],
) -> float | None:
    """How much of the space the vehicle was about to drive through it knew clear: for each
    sample of the controller's known space ``(t, origin, cell, state)``, the cells its
    outline swept over the next ``KNOWN_AHEAD_S`` (by its odometry, the frame of the known
    space), less those under the outline at ``t``, and the fraction of them known clear
    then; the mean over the samples after which it moved at least ``KNOWN_AHEAD_MIN_M``.
    ``None`` without such a sample. A vehicle that drives only where it knows the way has 1
    by its safety rule once there; this says how far ahead it knew it."""
    from agent.control.clearance import CLEAR

    if not samples or len(odometry) < 2:
        return None
    odo = np.asarray(odometry, dtype=np.float64)
    body = _body_points(samples[0][2])

    def cell_keys(poses: np.ndarray, origin: np.ndarray, cell: float) -> np.ndarray:
        """The distinct cells of the outline at ``poses``, each (row, column) as one integer
        (``np.unique(..., axis=1)`` over the pairs sorts column tuples, ten times slower)."""
        ij = _outline_cells(poses, body, origin, cell).reshape(2, -1)
        return np.unique((ij[0] + _KEY_OFFSET) * _KEY_BASE + (ij[1] + _KEY_OFFSET))

    fractions = []
    for t, origin, cell, state in samples:
        ahead = odo[(odo[:, 0] > t) & (odo[:, 0] <= t + KNOWN_AHEAD_S), 1:]
        now = odo[odo[:, 0] <= t, 1:][-1:]
        if ahead.shape[0] < 2 or now.shape[0] == 0:
            continue
        if float(np.sum(np.hypot(*np.diff(np.concatenate([now, ahead])[:, :2], axis=0).T))) < (
            KNOWN_AHEAD_MIN_M
        ):
            continue
        keys = cell_keys(ahead[_thinned(_outline_motion(ahead), 0.5 * cell)], origin, cell)
        keys = keys[~np.isin(keys, cell_keys(now, origin, cell))]
        swept = np.stack([keys // _KEY_BASE - _KEY_OFFSET, keys % _KEY_BASE - _KEY_OFFSET])
        inside = (swept[0] >= 0) & (swept[0] < state.shape[0])
        inside &= (swept[1] >= 0) & (swept[1] < state.shape[1])
        if not swept.shape[1]:
            continue
        known_clear = np.zeros(swept.shape[1], dtype=bool)
        known_clear[inside] = state[swept[0, inside], swept[1, inside]] == CLEAR
        fractions.append(float(known_clear.mean()))
    return float(np.mean(fractions)) if fractions else None


def _body_points(cell_m: float) -> np.ndarray:
    """(m, 2) points over the vehicle's outline, half a cell apart and off the cells' edges
    (none is passed over)."""
    step = 0.5 * cell_m
    half_l, half_w = 0.5 * VEHICLE.length_m, 0.5 * VEHICLE.width_m
    gx, gy = np.meshgrid(
        np.arange(-half_l + 0.5 * step, half_l, step), np.arange(-half_w + 0.5 * step, half_w, step)
    )
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def _outline_motion(poses: np.ndarray) -> np.ndarray:
    """(k,) m: how far the outline's furthest point has moved by each of ``k`` poses (x, y,
    yaw), at most: the path length plus the circumradius times the heading turned."""
    step = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    turn = np.abs(np.angle(np.exp(1j * np.diff(poses[:, 2]))))
    return np.concatenate([[0.0], np.cumsum(step + VEHICLE.circumradius_m * turn)])


def _thinned(motion: np.ndarray, step_m: float) -> np.ndarray:
    """Indices into poses whose outline ``motion`` (:func:`_outline_motion`, non-decreasing)
    is given: the first pose of each ``step_m`` of it, and the last. The scores below walk
    the outline over these only: odometry comes at 20 Hz whether the vehicle moves or not,
    and a vehicle that crept for a metre gave thousands of poses a sample (most of the
    evaluation's scoring time)."""
    if motion.size == 0:
        return np.zeros(0, dtype=np.int64)
    bins = np.floor((motion - motion[0]) / step_m)
    keep = np.flatnonzero(np.concatenate([[True], bins[1:] != bins[:-1]]))
    if keep[-1] != motion.size - 1:
        keep = np.append(keep, motion.size - 1)
    return keep


def _outline_cells(
    poses: np.ndarray, body: np.ndarray, origin: np.ndarray, cell: float
) -> np.ndarray:
    """(2, k, m) the (row, column) cells of ``body`` at each of the ``k`` poses."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    x = poses[:, None, 0] + c[:, None] * body[None, :, 0] - s[:, None] * body[None, :, 1]
    y = poses[:, None, 1] + s[:, None] * body[None, :, 0] + c[:, None] * body[None, :, 1]
    return np.stack([np.floor((y - origin[1]) / cell), np.floor((x - origin[0]) / cell)]).astype(
        np.int64
    )


def known_way(
    samples: list[tuple[float, np.ndarray, float, np.ndarray]],
    odometry: list[tuple[float, float, float, float]],
) -> float | None:
    """How far along the way it then drove the vehicle knew the space clear: for each
    sample of the controller's known space, the distance the vehicle went (by its odometry)
    before its outline first covered a cell not known clear at the sample, up to
    ``KNOWN_WAY_M``; the mean over the samples after which it went at least that far.
    ``None`` without one. Unlike :func:`known_ahead`, which the safety rule holds near 1,
    this separates a head that looks down the way from one that does not."""
    from agent.control.clearance import CLEAR

    if not samples or len(odometry) < 2:
        return None
    odo = np.asarray(odometry, dtype=np.float64)
    travel = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(odo[:, 1:3], axis=0).T))])
    motion = _outline_motion(odo[:, 1:])
    body = _body_points(samples[0][2])
    known = []
    for t, origin, cell, state in samples:
        start = int(np.searchsorted(odo[:, 0], t, side="right")) - 1
        if start < 0:
            continue
        gone = travel - travel[start]
        way = np.flatnonzero((np.arange(odo.shape[0]) >= start) & (gone <= KNOWN_WAY_M))
        if gone[-1] < KNOWN_WAY_M or way.size < 2:
            continue
        way = way[_thinned(motion[way], 0.5 * cell)]
        ij = _outline_cells(odo[way, 1:], body, origin, cell)
        inside = (ij[0] >= 0) & (ij[0] < state.shape[0]) & (ij[1] >= 0) & (ij[1] < state.shape[1])
        clear = np.zeros(ij.shape[1:], dtype=bool)
        clear[inside] = state[ij[0][inside], ij[1][inside]] == CLEAR
        ok = clear.all(axis=1)
        first_bad = int(np.argmin(ok)) if not ok.all() else way.size
        known.append(float(gone[way[first_bad - 1]]) if first_bad > 0 else 0.0)
    return float(np.mean(known)) if known else None


def _mean_speed(true_path: np.ndarray, time_s: float) -> float | None:
    """The true path's length over the run's time (m/s)."""
    if time_s <= 0 or true_path.shape[0] < 2:
        return None
    return float(np.sum(np.hypot(*np.diff(true_path, axis=0).T)) / time_s)


def _time_decisions(nodes: list[Node]) -> list[int]:
    """The wall time of each decision of the planner's head policy, in µs, collected in the
    list returned (empty for the passive policies, which decide nothing): the agent's
    stages keep no clock, so the bench times them from outside."""
    times: list[int] = []
    for node in nodes:
        policy = getattr(node.stage, "policy", None)
        decide = getattr(policy, "decide", None)
        if node.name != "planner" or decide is None:
            continue

        def timed(*args: Any, _decide: Any = decide) -> Any:
            started = time.perf_counter_ns()
            out = _decide(*args)
            times.append((time.perf_counter_ns() - started + 500) // 1000)
            return out

        policy.decide = timed  # type: ignore[union-attr]
    return times


def yaw_deg(yaw_rad: float) -> float:
    return math.degrees(math.remainder(yaw_rad, math.tau))


def scored_record(
    world: World,
    task: Task,
    label: str,
    outcome: str,
    collision_by: str | None,
    time_s: float,
    min_clearance_m: float,
    true_path: np.ndarray,
    final_pose: tuple[float, float, float],
    extra: dict[str, Any] | None = None,
    collision_with: str | None = None,
) -> Any:
    """A run's record (:class:`cli.evaluate.RunRecord`), scored against the true world: the
    docking error (dock), the reference path, the path ratio, the normalised score and
    ``extra["progress"]`` (:func:`progress`)."""
    from agent.scoring.closed_loop import dock_error, docking_face, normalised_score
    from agent.scoring.paths import path_ratio, reference_path
    from cli.evaluate import RunRecord, downsample_path

    dock_mm = dock_deg = None
    if task.kind == "dock":
        face = docking_face(world, task)
        dock_mm, dock_deg = dock_error(
            final_pose, face.ends, face.normal, task.dock_distance_m, VEHICLE.head_offset_m
        )
    shortest = reference_path(world, task).length_m
    finite = math.isfinite(shortest) and shortest > 0.0
    x, y, yaw = final_pose
    extra = {
        **(extra or {}),
        "progress": progress(world, task, (x, y), shortest) if finite else None,
    }
    return RunRecord(
        world=label, task=task.kind, outcome=outcome, collision_by=collision_by,
        collision_with=collision_with, time_s=time_s, min_clearance_m=min_clearance_m,
        path_ratio=path_ratio(true_path, shortest) if finite else None,
        score=normalised_score(outcome == "success", time_s, shortest) if finite else 0.0,
        dock_error_mm=dock_mm, dock_error_deg=dock_deg, final_pose=(x, y, yaw_deg(yaw)),
        shortest_path_m=shortest if finite else None, sim_time_s=time_s,
        true_path=downsample_path(true_path), extra=extra,
    )  # fmt: skip


def progress(
    world: World, task: Task, end_xy: tuple[float, float], start_m: float | None = None
) -> float:
    """How much of the way the vehicle made: ``1 − L(end)/L(start)``, ``L`` the reference
    path's length to the task's end (:func:`agent.scoring.paths.reference_path`, on the true
    world) from the world's start and from ``end_xy``; at most 1, negative when it ended
    further from the goal than it began. ``start_m``: ``L(start)`` when the caller has it
    (found here otherwise). From an end where no reference path starts (against an obstacle,
    after a collision), the straight distance to the goal stands for ``L(end)`` (a lower
    bound). A continuous figure beside the all-or-nothing success: which runs came near, and
    how near."""
    from agent.scoring.paths import reference_goal, reference_path

    start = reference_path(world, task).length_m if start_m is None else start_m
    if not (math.isfinite(start) and start > 0.0):
        raise ValueError(f"progress: no reference path from the start (length {start})")
    left = reference_path(world, task, start_xy=end_xy).length_m
    if not math.isfinite(left):
        left = math.dist(end_xy, reference_goal(world, task, VEHICLE))
    return min(1.0, 1.0 - left / start)


def run_record(spec: Any) -> Any:
    """One evaluation run (:class:`cli.evaluate.RunSpec`) to its record
    (:class:`cli.evaluate.RunRecord`): the closed loop, scored against the true world."""
    result = run_closed_loop(spec.world, spec.task, spec.policy, spec.controller, spec.noise_seed)
    return scored_record(
        spec.world, spec.task, spec.world_label, result.outcome, result.collision_by,
        result.time_s, result.min_clearance_m, result.true_path, result.final_pose,
        {
            "stopped_stale_s": result.stopped_stale_s, "arrived_wrong": result.arrived_wrong,
            "loop_wall_s": result.wall_s, "decision_us": result.decision_us,
            "path_known_ahead": result.path_known_ahead, "known_way_m": result.known_way_m,
            "mean_speed_m_s": _mean_speed(result.true_path, result.time_s),
            "standing_s": result.standing_s,
        },
        result.collision_with,
    )  # fmt: skip
