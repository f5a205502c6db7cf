"""What the closed loop would do if the controller knew the static world (not a test).

A diagnostic that splits the closed loop's failures between what the vehicle does not know
and what it does with what it knows: evaluate's random runs in lock-step, each with the
controller's known-clear grid replaced, after every environment vector, by the true static
world (a cell is clear when no wall, box or cylinder comes within half its diagonal of its
centre, in ``odom`` carried to the world by the true pose against the odometry's).
Everything else is as the agent has it: the movers are the vector's (its capsules and the
controller's memory of lost ones), the navigation field is built from the vector, the
controller looks and faces as it does. Truth never reaches the agent in the product; only
this tool reaches into the controller.

What it showed (24 runs, seed 0, 2026-11-27), ``forward`` / ``active``: 1 / 1 success,
14 / 11 collisions with walkers (11 / 8 with the vehicle moving), 4 / 4 runs ended where the
odometry put the goal but outside its tolerance, 5 / 8 timeouts. Before the controller's
walker changes of that day (a mover's inflation capped at the static 0.25 m, lost walkers
predicted on along their velocity): 0 / 1, 19 / 16 (17 / 12), 3 / 6, 2 / 1. Knowing the
static world does not make the loop work: walkers come from beside the vehicle, where the
window does not look, and odometry drift is the second cause.

    .venv/bin/python -m tests.unit.control.oracle_closed_loop [--random 24] [--seed 0]
        [--policy forward] [--runs 0,5,7]
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
from typing import Any

import numpy as np

from agent.control.clearance import BLOCKED, CLEAR
from agent.runtime.messages import Message
from agent.runtime.stage import Output, Stage
from agent.sim.world import World
from cli.closed_loop import run_closed_loop
from cli.evaluate import random_specs, random_task_source


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, k) distances from points ``p`` (n, 2) to segments ``a → b`` (k, 2)."""
    ab = b - a
    length2 = np.maximum(np.einsum("kd,kd->k", ab, ab), 1e-12)
    t = np.clip(np.einsum("nkd,kd->nk", p[:, None, :] - a[None], ab) / length2, 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.asarray(np.linalg.norm(p[:, None, :] - closest, axis=-1))


def true_clear(world: World, points_xy: np.ndarray, margin_m: float) -> np.ndarray:
    """(n,) bool: no static wall, box or cylinder of ``world`` within ``margin_m`` of each
    point (world frame)."""
    free = np.ones(points_xy.shape[0], dtype=bool)
    if len(world.segments_start):
        d = _segment_distance(points_xy, world.segments_start, world.segments_end)
        free &= d.min(axis=1) > margin_m
    if len(world.circles_center):
        d = np.linalg.norm(points_xy[:, None, :] - world.circles_center[None], axis=-1)
        free &= (d - world.circles_radius[None]).min(axis=1) > margin_m
    return free


class _Knowing(Stage):
    """The vehicle stage, its controller's known-clear grid made the truth after each
    vector (module docstring)."""

    def __init__(self, vehicle: Any, world: World, world_stage: Any) -> None:
        self.vehicle, self.world, self.world_stage = vehicle, world, world_stage

    def start(self, now_s: float) -> list[Output]:
        return list(self.vehicle.start(now_s))

    def next_tick_s(self) -> float | None:
        return self.vehicle.next_tick_s()  # type: ignore[no-any-return]

    def tick(self, now_s: float) -> list[Output]:
        return list(self.vehicle.tick(now_s))

    def counters(self) -> dict[str, int]:
        return dict(self.vehicle.counters())

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        out = list(self.vehicle.handle(topic, msg, now_s))
        controller = self.vehicle.controller
        local = controller._local
        if topic == "environment" and local is not None and controller._count:
            self._know(controller, local)
        return out

    def _know(self, controller: Any, local: Any) -> None:
        odom = controller._odometry[controller._count - 1, 1:4]
        truth = self.world_stage
        turn = truth.yaw - odom[2]
        c, s = math.cos(turn), math.sin(turn)
        ny, nx = local.state.shape
        cols, rows = np.meshgrid(np.arange(nx), np.arange(ny))
        x = local.origin_xy[0] + (cols + 0.5) * local.cell_m - odom[0]
        y = local.origin_xy[1] + (rows + 0.5) * local.cell_m - odom[1]
        world_xy = np.stack([c * x - s * y + truth.x, s * x + c * y + truth.y], axis=-1)
        half_diagonal = 0.5 * math.sqrt(2.0) * local.cell_m
        free = true_clear(self.world, world_xy.reshape(-1, 2), half_diagonal).reshape(ny, nx)
        # The vector's movers stay as the controller has them (but not one holding the
        # vehicle, which the controller checks apart).
        caps = controller._capsules
        if caps is not None and len(caps):
            cells_xy = np.stack([x + odom[0], y + odom[1]], axis=-1).reshape(
                -1, 2
            )  # odom, as the capsules
            reach = caps.reach
            clear_of_vehicle = _segment_distance(odom[None, :2], caps.a, caps.b)[0] > (
                controller.spec.circumradius_m + reach
            )
            keep = caps.moving & clear_of_vehicle
            if keep.any():
                hit = _segment_distance(cells_xy, caps.a[keep], caps.b[keep]) <= (
                    reach[keep] + half_diagonal
                )
                free &= ~hit.any(axis=1).reshape(ny, nx)
        local.state[...] = np.where(free, CLEAR, BLOCKED)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--random", type=int, default=24, help="evaluate's --random N")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--policy", default="forward")
    parser.add_argument("--runs", help="comma-separated run indices (default: all N)")
    args = parser.parse_args()
    indices = [int(i) for i in args.runs.split(",")] if args.runs else list(range(args.random))
    specs = random_specs(args.random, args.seed, args.policy, indices, random_task_source)
    outcomes: Counter[str] = Counter()
    driven = times = 0.0
    for spec in specs:
        holder: dict[str, Any] = {}

        def wrap(
            name: str, stage: Stage, holder: dict[str, Any] = holder, world: World = spec.world
        ) -> Stage:
            holder[name] = stage
            if name == "vehicle":
                return _Knowing(stage, world, holder["world"])
            return stage

        result = run_closed_loop(
            spec.world, spec.task, args.policy, "default", spec.noise_seed, wrap_stage=wrap
        )
        key = result.outcome
        if result.outcome == "collision":
            key += f" with a {result.collision_with} (the {result.collision_by} moving)"
        elif result.arrived_wrong:
            key += " (arrived where its odometry put the goal)"
        outcomes[key] += 1
        length = float(np.sum(np.hypot(*np.diff(result.true_path, axis=0).T)))
        driven += length
        times += result.time_s
        print(
            f"run {spec.index:3d} {spec.task.kind:5s} {key:45s} at {result.time_s:6.1f} s, "
            f"{length:5.1f} m driven"
        )
    print(f"\n{len(specs)} runs, {args.policy}, the static world known:")
    for key, n in outcomes.most_common():
        print(f"  {n:3d}  {key}")
    print(f"  mean speed {driven / max(times, 1e-9):.3f} m/s")


if __name__ == "__main__":
    main()
