"""Trace one closed-loop run: what the controller did and why, second by second (not a test).

Runs evaluate's random world ``INDEX`` (the world, task and noise seed of ``sensor-agent
evaluate --random N --seed S``, for any N > INDEX) in lock-step and prints, every ``--every``
simulated seconds and at each change of the controller's mode or reason, the true pose, the
command and ``mode/reason``; then the share of the run each mode/reason took, the distance
driven, and how the run ended (a collision with what, where on the vehicle).

What it showed first: the vehicle boxed in after turns ("unknown_ahead", "looking") and the
walkers that meet its flank (the README's closed-loop section).

Run: ``.venv/bin/python -m tests.unit.control.trace_closed_loop INDEX [--seed 0]
[--policy forward] [--controller default] [--until 60] [--every 1]``.
"""

from __future__ import annotations

import argparse
import math
from collections import Counter

import numpy as np

from agent.runtime.lockstep import LockstepRunner
from agent.sim.world_file import load_world
from cli.closed_loop import closed_loop_nodes
from cli.evaluate import random_specs, random_task_source

STEP_S = 0.05  # the controller's period: every command is seen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("index", type=int, help="the random run's index (-1: --world)")
    parser.add_argument("--world", help="a world file with a [task] (with index -1)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--policy", default="forward")
    parser.add_argument("--controller", default="default")
    parser.add_argument("--until", type=float, default=None, help="simulated s (task's limit)")
    parser.add_argument("--every", type=float, default=1.0, help="simulated s between lines")
    args = parser.parse_args()

    if args.index < 0:
        world = load_world(args.world)
        assert world.task is not None, f"{args.world}: no [task]"
        task, noise_seed = world.task, 0  # the demo's seed
    else:
        n = args.index + 1
        (spec,) = random_specs(n, args.seed, args.policy, [args.index], random_task_source)
        world, task, noise_seed = spec.world, spec.task, spec.noise_seed
    nodes, world_stage, vehicle = closed_loop_nodes(
        world, task, args.policy, args.controller, noise_seed
    )
    until = task.time_limit_s if args.until is None else args.until
    print(f"run {args.index} (seed {args.seed}): {world.name}; {task.kind} to {task.goal}")
    runner = LockstepRunner(nodes)
    shares: Counter[str] = Counter()
    driven, last_xy, last_key, next_line = 0.0, None, "", 0.0
    t = 0.0
    while t < until and not world_stage.collision:
        t += STEP_S
        runner.run_until(t)
        out = vehicle.last
        xy = np.array([world_stage.x, world_stage.y])
        if last_xy is not None:
            driven += float(np.hypot(*(xy - last_xy)))
        last_xy = xy
        if out is None:
            continue
        key = f"{out.mode}/{out.reason}"
        shares[key] += 1
        if t >= next_line or key != last_key:
            print(
                f"{t:7.2f} s  x {world_stage.x:6.2f}  y {world_stage.y:6.2f}  "
                f"yaw {math.degrees(world_stage.yaw):7.1f}°  v {out.speed_m_s:+.2f}  "
                f"w {out.yaw_rate_rad_s:+.2f}  {key}"
            )
            next_line = max(next_line + args.every, t) if t >= next_line else next_line
        last_key = key
    total = sum(shares.values()) or 1
    print("share of the run:", ", ".join(f"{k} {v / total:.0%}" for k, v in shares.most_common()))
    print(f"driven {driven:.2f} m in {t:.1f} s")
    if world_stage.collision:
        mover = world_stage.collision_obstacle >= world.mover_id_base
        print(
            f"collision at {world_stage.collision_time_s:.2f} s by the {world_stage.collision}, "
            f"with {'a mover' if mover else 'something static'}"
        )


if __name__ == "__main__":
    main()
