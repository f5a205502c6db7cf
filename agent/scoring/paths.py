"""Path lengths for scoring a closed-loop run: the reference path and the path ratio.

Frames follow REP-103; metres, world frame.

* **The reference path** (:func:`reference_path`): the shortest path, through the true
  static world, of a disc of the vehicle's inradius (0.3 m) from the start to the goal; for a
  dock task, to ``base_link``'s docking pose (:func:`agent.scoring.closed_loop.dock_pose`).
  No path the 0.8 m × 0.6 m vehicle can drive is shorter (a disc inside its outline goes
  wherever it goes). Its length over 0.5 m/s is the score's ``T_ref``
  (:func:`agent.scoring.closed_loop.normalised_score`). The grid search and its
  discretisation error are :mod:`agent.sim.paths`' (re-exported here): the grid's free
  space is widened by ``√2·h`` so as to lose no true passage, and the length, pulled
  straight, is exact where start and goal see each other and otherwise at most 2.8 % above
  the shortest path among the free cells.
* **The path ratio** (:func:`path_ratio`): the length of the true path driven over the
  reference path's.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from agent.kinematics.vehicle import VehicleSpec
from agent.scoring.closed_loop import dock_pose, docking_face
from agent.sim.paths import (
    CELL_M,
    PathResult,
    reference_radius_m,
    shortest_path,
    turning_radius_m,
)
from agent.sim.world import World
from agent.task import Task

__all__ = [
    "PathResult",
    "path_length_m",
    "path_ratio",
    "reference_goal",
    "reference_path",
    "reference_radius_m",
    "shortest_path",
    "turning_radius_m",
]


def reference_goal(
    world: World, task: Task, vehicle: VehicleSpec | None = None
) -> tuple[float, float]:
    """Where ``base_link`` ends a task: the goal, or for dock the docking pose's position.

    Raises
    ------
    ValueError
        For a dock task in a world without a docking target.
    """
    if task.kind != "dock":
        return task.goal
    spec = vehicle if vehicle is not None else VehicleSpec()
    face = docking_face(world, task)
    x, y, _ = dock_pose(face.ends, face.normal, task.dock_distance_m, spec.head_offset_m)
    return x, y


def reference_path(
    world: World,
    task: Task,
    start_xy: npt.ArrayLike | None = None,
    vehicle: VehicleSpec | None = None,
    cell_m: float = CELL_M,
) -> PathResult:
    """The reference path for ``task`` in ``world`` (module docstring).

    Parameters
    ----------
    world
        The true world (movers are ignored).
    task
        The task; its goal, or for dock its docking pose, ends the path.
    start_xy
        (2,) metres, world frame; default the world's ``vehicle_pose``.
    vehicle
        The outline (default :class:`VehicleSpec` ``()``).
    cell_m
        The grid's cell side, metres.

    Returns
    -------
    PathResult
        ``inf`` length when there is no such path.
    """
    spec = vehicle if vehicle is not None else VehicleSpec()
    start = world.vehicle_pose[:2] if start_xy is None else start_xy
    goal = reference_goal(world, task, spec)
    return shortest_path(world, start, goal, reference_radius_m(spec, cell_m), cell_m)


def path_length_m(xy: npt.ArrayLike) -> float:
    """The length of a polyline ``xy`` (k, 2), metres (0 for fewer than two points)."""
    p = np.asarray(xy, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or not np.all(np.isfinite(p)):
        raise ValueError(f"xy must be finite points of shape (k, 2), got shape {p.shape}")
    return float(np.hypot(*np.diff(p, axis=0).T).sum())


def path_ratio(driven_xy: npt.ArrayLike, shortest_path_m: float) -> float:
    """The length of the driven path ``driven_xy`` (k, 2) over ``shortest_path_m``.

    Raises
    ------
    ValueError
        For a path of the wrong shape, or a shortest path that is not positive and finite.
    """
    if not (math.isfinite(shortest_path_m) and shortest_path_m > 0.0):
        raise ValueError(f"shortest_path_m must be positive and finite, got {shortest_path_m!r}")
    return path_length_m(driven_xy) / shortest_path_m
