"""Benchmark: the closed loop in lock-step, stage by stage (not a test).

Runs evaluate's random tasks (the worlds, tasks and noise seeds of ``sensor-agent evaluate
--random N --seed S --policy P --jobs 1``) through :func:`cli.closed_loop.run_closed_loop`,
each stage wrapped so that its ``start``, ``tick`` and ``handle`` calls are timed, and prints
per stage its CPU seconds (``time.process_time``: less sensitive than the wall clock to the
machine's other work), its share and its milliseconds per simulated second; the runner's own
share (everything outside the stages: the lock-step runner, the header stamps, the loop's
checks, the wrappers); and the realtime factor per core, simulated seconds over wall and over
CPU seconds of the loops. A short run first loads the compiled kernels (its time is printed,
not counted: evaluate's first run pays it). ``--profile N``: the runs under cProfile, then
the N functions with the most own time and the N with the most time below them.

Run: ``.venv/bin/python -m tests.unit.bench_closed_loop [--random 4] [--seed 0]
[--policy forward] [--controller default] [--profile 40]``.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import pstats
import time
from collections import defaultdict
from typing import Any

from agent.runtime.messages import Message
from agent.runtime.stage import Output, Stage
from cli.closed_loop import run_closed_loop
from cli.evaluate import random_specs, random_task_source


class TimedStage(Stage):
    """Calls ``stage`` and adds the wall and CPU seconds of each call to ``name``'s totals."""

    def __init__(self, name: str, stage: Stage, wall: dict[str, float], cpu: dict[str, float]):
        self.name, self.stage, self.wall, self.cpu = name, stage, wall, cpu

    def _timed(self, call: Any, *args: Any) -> list[Output]:
        wall, cpu = time.perf_counter(), time.process_time()
        out: list[Output] = call(*args)
        self.cpu[self.name] += time.process_time() - cpu
        self.wall[self.name] += time.perf_counter() - wall
        return out

    def prepare(self) -> None:
        self.stage.prepare()

    def start(self, now_s: float) -> list[Output]:
        return self._timed(self.stage.start, now_s)

    def handle(self, topic: str, msg: Message, now_s: float) -> list[Output]:
        return self._timed(self.stage.handle, topic, msg, now_s)

    def tick(self, now_s: float) -> list[Output]:
        return self._timed(self.stage.tick, now_s)

    def next_tick_s(self) -> float | None:
        return self.stage.next_tick_s()

    def counters(self) -> dict[str, int]:
        return self.stage.counters()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--random", type=int, default=4, metavar="N")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--policy", default="forward")
    parser.add_argument("--controller", choices=("default", "dwa"), default="default")
    parser.add_argument("--profile", type=int, default=0, metavar="N")
    args = parser.parse_args(argv)
    specs = random_specs(args.random, args.seed, args.policy, range(args.random),
                         random_task_source)  # fmt: skip

    started = time.perf_counter()
    first = specs[0]
    run_closed_loop(first.world, dataclasses.replace(first.task, time_limit_s=1.0),
                    args.policy, args.controller, first.noise_seed)  # fmt: skip
    print(f"loading (a 1 s run first, not counted): {time.perf_counter() - started:.2f} s wall")

    wall: dict[str, float] = defaultdict(float)
    cpu: dict[str, float] = defaultdict(float)
    profile = cProfile.Profile() if args.profile else None
    sim_s = loop_wall_s = loop_cpu_s = 0.0
    for spec in specs:
        cpu_started = time.process_time()
        if profile is not None:
            profile.enable()
        result = run_closed_loop(
            spec.world, spec.task, args.policy, args.controller, spec.noise_seed,
            wrap_stage=lambda name, stage: TimedStage(name, stage, wall, cpu),
        )  # fmt: skip
        if profile is not None:
            profile.disable()
        loop_cpu_s += time.process_time() - cpu_started
        loop_wall_s += result.wall_s
        sim_s += result.time_s
        print(f"  run {spec.index}: {spec.world_label}: {result.outcome} at "
              f"{result.time_s:.1f} s simulated, {result.wall_s:.2f} s wall")  # fmt: skip
    print(f"{args.random} runs, {sim_s:.1f} s simulated: {loop_wall_s:.2f} s wall, "
          f"{loop_cpu_s:.2f} s CPU")  # fmt: skip
    print(f"{'stage':>12} {'CPU s':>8} {'share':>7} {'ms per sim s':>13} {'wall s':>8}")
    for name in sorted(cpu, key=lambda k: -cpu[k]):
        print(f"{name:>12} {cpu[name]:8.3f} {cpu[name] / loop_cpu_s:7.1%} "
              f"{1e3 * cpu[name] / sim_s:13.2f} {wall[name]:8.3f}")  # fmt: skip
    rest = loop_cpu_s - sum(cpu.values())
    print(f"{'runner':>12} {rest:8.3f} {rest / loop_cpu_s:7.1%} {1e3 * rest / sim_s:13.2f}")
    print(f"realtime factor per core: {sim_s / loop_wall_s:.1f} (wall), "
          f"{sim_s / loop_cpu_s:.1f} (CPU)")  # fmt: skip
    if profile is not None:
        stats = pstats.Stats(profile)
        stats.sort_stats("tottime").print_stats(args.profile)
        stats.sort_stats("cumtime").print_stats(args.profile)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
