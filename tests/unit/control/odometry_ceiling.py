"""The best any controller on odometry alone can do: the drift ceiling of the random tasks.

The environment vector and the odometry are in ``odom``; a task's goal is in the world
frame, which ``odom`` equals only at the start. A vehicle that drives the reference path of
its task exactly and stops where its odometry says the goal is, is off the goal by the
odometry's error at the end. This drives each random task's reference path (turn on the spot
to each leg, drive it straight; for park, turn to the goal's heading at the end) through the
simulated odometry (:class:`agent.sim.odometry.WheelOdometry`) for many vehicles at once,
each with its own wheel errors drawn from the model, and counts how many end within the
task's tolerance (goto: 0.3 m; park: 0.3 m and 5°; dock: the head within 5 mm and 0.5° of
its docking pose, which no controller reaches by odometry: it must find the target in the
environment vector, so dock is reported apart).

    .venv/bin/python -m tests.unit.control.odometry_ceiling [--tasks 200] [--seed 0]
        [--vehicles 200] [--systematic-scale 1.0]

``--systematic-scale`` multiplies the model's wheel scale, ratio and track spreads (0.1: a
vehicle calibrated as UMBmark calibrates one, its systematic errors an order of magnitude
smaller).
"""

from __future__ import annotations

import argparse
import itertools
import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from agent.scoring.paths import reference_path
from agent.sim.odometry import OdometryErrorModel, WheelOdometry
from agent.sim.taskgen import random_tasks
from agent.sim.world import World
from agent.task import Task


@dataclass(frozen=True)
class Ceiling:
    """One task: its kind, reference path length (m), the median end error (m) over the
    vehicles, and the fraction of them within the task's tolerance."""

    kind: str
    path_m: float
    median_error_m: float
    within: float


def task_ceiling(
    world: World, task: Task, model: OdometryErrorModel, vehicles: int, seed: int
) -> Ceiling | None:
    """The drift ceiling of one task (module docstring); ``None`` without a reference path."""
    ref = reference_path(world, task)
    if not math.isfinite(ref.length_m):
        return None
    x0, y0, yaw = world.vehicle_pose
    odometry = WheelOdometry(model, np.random.default_rng(seed), (x0, y0, yaw), runs=vehicles)
    for a, b in itertools.pairwise(ref.waypoints):
        leg = float(np.hypot(*(b - a)))
        if leg < 1e-9:
            continue
        turn = math.remainder(math.atan2(b[1] - a[1], b[0] - a[0]) - yaw, math.tau)
        odometry.advance(0.0, turn)
        yaw += turn
        odometry.advance(leg, 0.0)
    if task.kind == "park" and task.goal_yaw_rad is not None:
        turn = math.remainder(task.goal_yaw_rad - yaw, math.tau)
        odometry.advance(0.0, turn)
        yaw += turn
    end = ref.waypoints[-1]
    pose = odometry.pose
    error = np.hypot(pose[:, 0] - end[0], pose[:, 1] - end[1])
    heading = np.abs(np.remainder(pose[:, 2] - yaw + math.pi, math.tau) - math.pi)
    ok = error <= task.tolerance_m
    if task.kind == "park":
        ok &= heading <= task.tolerance_rad
    return Ceiling(task.kind, ref.length_m, float(np.median(error)), float(ok.mean()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--tasks", type=int, default=200, help="random tasks (200)")
    parser.add_argument("--seed", type=int, default=0, help="the tasks' seed (0)")
    parser.add_argument("--vehicles", type=int, default=200, help="vehicles per task (200)")
    parser.add_argument(
        "--systematic-scale", type=float, default=1.0,
        help="multiply the wheel scale, ratio and track spreads (1.0)",
    )  # fmt: skip
    args = parser.parse_args(argv)
    base = OdometryErrorModel()
    f = args.systematic_scale
    model = OdometryErrorModel(
        track_m=base.track_m, scale_sigma=base.scale_sigma * f,
        ratio_sigma=base.ratio_sigma * f, track_sigma=base.track_sigma * f,
        slip_m=base.slip_m,
    )  # fmt: skip
    by_kind: dict[str, list[Ceiling]] = defaultdict(list)
    for i, (world, task) in enumerate(random_tasks(args.tasks, args.seed)):
        c = task_ceiling(world, task, model, args.vehicles, seed=i)
        if c is not None:
            by_kind[c.kind].append(c)
    print(f"odometry alone, systematic spreads x{f:g} ({args.tasks} tasks, seed {args.seed})")
    for kind, cs in by_kind.items():
        print(
            f"  {kind:5s} {len(cs):4d} tasks, path median {np.median([c.path_m for c in cs]):.1f}"
            f" m, end error median {np.median([c.median_error_m for c in cs]):.2f} m, within"
            f" tolerance {np.mean([c.within for c in cs]):.3f}"
        )
    odo = [c for k in ("goto", "park") for c in by_kind.get(k, [])]
    n_dock = len(by_kind.get("dock", []))
    total = sum(c.within for c in odo) + n_dock
    print(f"  goto and park: {np.mean([c.within for c in odo]):.3f} of runs can succeed;")
    print(f"  all tasks, every dock counted a success: {total / (len(odo) + n_dock):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
