"""The lock-step closed loop (cli.closed_loop): a bench's stage wrappers change nothing."""

from __future__ import annotations

import dataclasses
from collections import defaultdict

import numpy as np

from agent.runtime.stage import Stage
from agent.sim.taskgen import random_tasks
from cli.closed_loop import run_closed_loop
from tests.unit.bench_closed_loop import TimedStage


def test_stages_wrapped_for_timing_give_the_same_run() -> None:
    world, task = random_tasks(1, 0)[0]
    task = dataclasses.replace(task, time_limit_s=3.0)
    plain = run_closed_loop(world, task, seed=5)
    wall: dict[str, float] = defaultdict(float)
    cpu: dict[str, float] = defaultdict(float)
    wrapped_names: list[str] = []

    def wrap(name: str, stage: Stage) -> Stage:
        wrapped_names.append(name)
        return TimedStage(name, stage, wall, cpu)

    timed = run_closed_loop(world, task, seed=5, wrap_stage=wrap)
    assert wrapped_names == ["world", "head", "calibration", "filtering", "features",
                             "tracking", "planner", "vehicle"]  # fmt: skip
    assert set(cpu) == set(wall) == set(wrapped_names)  # every stage was called and timed
    assert all(v > 0.0 for v in wall.values())
    for field in dataclasses.fields(plain):
        if field.name == "wall_s":
            continue
        a, b = getattr(plain, field.name), getattr(timed, field.name)
        if isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b)
        else:
            assert a == b, field.name
