"""A world's task: where the vehicle must go, and what counts as getting there.

World files state it in a ``[task]`` table (the keys are an interface; other tools write them)::

    [task]
    kind = "goto"          # "goto", "park" or "dock"
    goal = [6.0, 1.0]      # m, world frame
    goal_yaw_deg = 90.0    # "park" only (required there)
    tolerance_m = 0.3      # success radius for goto and park
    tolerance_deg = 5.0    # park: heading tolerance (default 5°)
    time_limit_s = 120.0
    dock_distance_m = 0.5  # "dock" only: the head's centre of scanning this far from the
                           # target's face, square to it

For ``dock``, ``goal`` is only the approximate position of the docking target (as a dock
database would hold it); the vehicle controller must find the target itself in the
environment vector and approach from what it sees.

Frames follow REP-103; metres, radians inside the code, degrees only in keys named ``*_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

__all__ = ["TASK_KINDS", "Task", "TaskKind"]

TaskKind = Literal["goto", "park", "dock"]
TASK_KINDS: tuple[TaskKind, ...] = ("goto", "park", "dock")


@dataclass(frozen=True)
class Task:
    """One task, world frame.

    Attributes
    ----------
    kind
        ``"goto"`` (reach ``goal`` within ``tolerance_m``), ``"park"`` (and face
        ``goal_yaw_rad`` within ``tolerance_rad``) or ``"dock"`` (stop with the head's centre of
        scanning ``dock_distance_m`` in front of the docking target near ``goal``, square to
        its face).
    goal
        (x, y), metres, world frame.
    goal_yaw_rad
        The heading to park at (``park`` only; ``None`` otherwise).
    tolerance_m, tolerance_rad
        Success radius (goto, park) and heading tolerance (park).
    time_limit_s
        The run fails as a timeout after this long.
    dock_distance_m
        ``dock`` only: the distance from the target's face to the centre of scanning.

    Raises
    ------
    ValueError
        For values outside the above (world files are checked with clear messages before
        they get here).
    """

    kind: TaskKind
    goal: tuple[float, float]
    goal_yaw_rad: float | None = None
    tolerance_m: float = 0.3
    tolerance_rad: float = math.radians(5.0)
    time_limit_s: float = 120.0
    dock_distance_m: float = 0.5

    def __post_init__(self) -> None:
        if self.kind not in TASK_KINDS:
            raise ValueError(f"Task.kind must be one of {TASK_KINDS}, got {self.kind!r}")
        goal = tuple(float(v) for v in self.goal)
        if len(goal) != 2 or not all(math.isfinite(v) for v in goal):
            raise ValueError(f"Task.goal must be two finite numbers, got {self.goal!r}")
        object.__setattr__(self, "goal", goal)
        if (self.kind == "park") != (self.goal_yaw_rad is not None):
            raise ValueError("Task.goal_yaw_rad is required for park and only for park")
        if self.goal_yaw_rad is not None and not math.isfinite(self.goal_yaw_rad):
            raise ValueError("Task.goal_yaw_rad must be finite")
        for name in ("tolerance_m", "tolerance_rad", "time_limit_s", "dock_distance_m"):
            value = float(getattr(self, name))
            if not math.isfinite(value) or value <= 0.0:
                raise ValueError(f"Task.{name} must be positive and finite, got {value!r}")
