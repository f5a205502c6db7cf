"""Benchmark: the controller's time per call on a scripted run with 40 obstacles in view.

``python -m tests.unit.control.bench_controller [--planner dwa] [--seeds 3]`` drives the
test harness's closed loop (:mod:`tests.unit.control.harness`) through seeded rooms of
boxes and cylinders (40 obstacles in every vector: the harness's ``all_known``) toward a goal
8 m away, timing each ``command``, ``update_environment`` and ``update_odometry`` call with
``time.perf_counter_ns``, and prints p50 / p99 / max per kind of call and per command period
(one command, half a vector and 2.5 odometry messages: the sum of all calls over the number
of commands). The compiled kernels are loaded first (:func:`agent.control.controller.warm_up`).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from agent.control.controller import warm_up
from agent.task import Task
from tests.unit.control.harness import Harness, Scene


def scene(seed: int) -> Scene:
    """A 10 m room (4 walls), 12 boxes (4 segments each) and 24 cylinders: 40 obstacles,
    none within 1 m of the start or the goal (8 m away on the x axis)."""
    rng = np.random.default_rng(seed)
    s = Scene()
    room = [(-2.0, -5.0), (10.0, -5.0), (10.0, 5.0), (-2.0, 5.0)]
    for i in range(4):
        s.segments.append((room[i], room[(i + 1) % 4]))
    placed = 0
    while placed < 36:
        c = rng.uniform([-1.5, -4.5], [9.5, 4.5])
        if min(math.hypot(*c), math.hypot(c[0] - 8.0, c[1])) < 1.5:
            continue
        if placed < 12:
            s.box(float(c[0]), float(c[1]), *rng.uniform(0.2, 0.6, 2).tolist())
        else:
            s.cylinders.append((float(c[0]), float(c[1]), float(rng.uniform(0.05, 0.3))))
        placed += 1
    return s


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--planner", choices=("default", "dwa"), default="default")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=40.0)
    args = parser.parse_args(argv)
    warm_up()
    times: dict[str, list[int]] = {"command": [], "update_environment": [], "update_odometry": []}
    commands = 0
    arrived = 0
    for seed in range(args.seeds):
        harness = Harness(scene(seed), Task("goto", (8.0, 0.0)), planner=args.planner,
                          all_known=True)  # fmt: skip
        ctl = harness.controller
        for name in times:
            original = getattr(ctl, name)

            def timed(*a: object, _f: object = original, _n: str = name) -> object:
                t0 = time.perf_counter_ns()
                out = _f(*a)  # type: ignore[operator]
                times[_n].append(time.perf_counter_ns() - t0)
                return out

            setattr(ctl, name, timed)
        record = harness.run(args.seconds)
        commands += len(record.t)
        arrived += record.arrived_s is not None
        print(
            f"seed {seed}: arrived at {record.arrived_s} s, collided {record.collided}, "
            f"min clearance {record.min_clearance_m:.3f} m"
        )
    print(f"planner {args.planner}: {arrived}/{args.seeds} arrived, {commands} commands")
    for name, values in times.items():
        v = np.array(values) / 1e6
        print(
            f"{name:>20}: n {v.size:6d}  p50 {np.percentile(v, 50):.3f} ms  "
            f"p99 {np.percentile(v, 99):.3f} ms  max {v.max():.3f} ms"
        )
    total = sum(sum(v) for v in times.values()) / 1e6
    print(f"{'per command period':>20}: {total / commands:.3f} ms (mean of all calls)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
