"""Scoring a finished closed-loop run against the true world: success, docking error,
score, and the interval on a success rate.

Frames follow REP-103 (x forward, y left, angles counter-clockwise); metres, seconds,
radians; degrees and millimetres only in names ending ``_deg`` and ``_mm``. Poses are
``(x_m, y_m, yaw_rad)`` of ``base_link`` in the world frame, as the simulator's truth has
them.

* **The docking face** (:func:`docking_face`): of the world's segments at least
  :data:`~agent.planning.environment.DOCKING_REFLECTIVITY` bright (what the agent reports as
  a docking target), the obstacle nearest the task's goal; of its faces, the longest (a
  plate's two long sides), and of those, and of their two normals, the one with the most
  room in front of it (a ray cast along the normal from the face's centre): the face toward
  the room, not the one a centimetre or two off the wall behind the plate.
* **The docking pose** (:func:`dock_pose`): the head's centre of scanning ``dock_distance_m``
  in front of the face's centre along its outward normal ``n``, the vehicle facing ``−n``
  (``base_link`` ``head_offset_m`` further out).
* **The docking error** (:func:`dock_error`): the distance of the true centre of scanning
  from that point, in mm, and the angle between the true heading and ``−n``, in degrees.
* **Success** (:func:`task_success`): goto, ``base_link`` within ``tolerance_m`` of the goal;
  park, that and the heading within ``tolerance_rad`` of ``goal_yaw_rad``; dock, the centre
  of scanning within ``tolerance_m`` of the docking point and the heading within
  :data:`DOCK_HEADING_TOLERANCE_RAD` (5°) of ``−n``. The docking error itself is reported
  beside success, whatever it is.
* **Score** (:func:`normalised_score`): ``success · T_ref / clip(T, 2·T_ref, 8·T_ref)`` with
  ``T_ref`` = the shortest path / 0.5 m/s: at most 1/2 (a run as fast as the reference or
  up to twice its time), 1/8 for a success that took 8 times the reference or longer, 0 for
  a failure.
* **Success rate** (:func:`wilson_interval`): the Wilson score interval of a binomial
  proportion (``scipy.stats.binomtest(...).proportion_ci(method="wilson")``); with no runs
  at all, NaNs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent.arrays import FloatArray
from agent.kinematics.vehicle import VehicleSpec
from agent.planning.environment import DOCKING_REFLECTIVITY
from agent.sim.raycast import cast_rays
from agent.sim.world import World
from agent.task import Task

__all__ = [
    "DOCK_HEADING_TOLERANCE_RAD",
    "REFERENCE_SPEED_M_S",
    "DockingFace",
    "dock_error",
    "dock_pose",
    "docking_face",
    "normalised_score",
    "task_success",
    "wilson_interval",
]

DOCK_HEADING_TOLERANCE_RAD = math.radians(5.0)
"""A dock succeeds only with the heading this close to square on to the face."""
REFERENCE_SPEED_M_S = 0.5
"""The speed the reference time is taken at: the vehicle's top speed."""


@dataclass(frozen=True)
class DockingFace:
    """A docking target's face, world frame.

    Attributes
    ----------
    ends
        (2, 2) float64, metres: the face's two end points.
    normal
        (2,) float64, unit: the outward normal, into the room the vehicle docks from.
    obstacle
        The id of the obstacle the face belongs to.
    """

    ends: FloatArray
    normal: FloatArray
    obstacle: int

    @property
    def centre(self) -> FloatArray:
        """(2,) metres: the middle of the face."""
        return np.asarray(0.5 * (self.ends[0] + self.ends[1]), dtype=np.float64)


def _pose(pose: npt.ArrayLike, what: str) -> FloatArray:
    p = np.asarray(pose, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{what} must be three finite numbers (x_m, y_m, yaw_rad), got {pose!r}")
    return p


def _wrap(angle_rad: float) -> float:
    """``angle_rad`` in [-π, π]."""
    return math.remainder(angle_rad, 2.0 * math.pi)


def _face(face: npt.ArrayLike, normal: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    ends = np.asarray(face, dtype=np.float64)
    n = np.asarray(normal, dtype=np.float64)
    if ends.shape != (2, 2) or not np.all(np.isfinite(ends)):
        raise ValueError(f"face must be two finite end points, shape (2, 2), got {face!r}")
    length = float(np.hypot(*n)) if n.shape == (2,) else math.nan
    if not (math.isfinite(length) and length > 0.0):
        raise ValueError(f"normal must be a finite non-zero (2,) vector, got {normal!r}")
    return ends, n / length


def docking_face(world: World, task: Task) -> DockingFace:
    """The face of the docking target a dock task means (module docstring).

    Parameters
    ----------
    world
        The true world.
    task
        Its ``goal`` says which target (the nearest); any kind is accepted.

    Returns
    -------
    DockingFace

    Raises
    ------
    ValueError
        If no segment of the world is at least ``DOCKING_REFLECTIVITY`` bright.
    """
    bright = np.flatnonzero(world.segments_reflectivity >= DOCKING_REFLECTIVITY)
    if bright.size == 0:
        raise ValueError(
            f"world {world.name!r} has no docking target (reflectivity >= {DOCKING_REFLECTIVITY})"
        )
    a, b = world.segments_start, world.segments_end
    goal = np.asarray(task.goal, dtype=np.float64)
    e = b[bright] - a[bright]
    t = np.clip(np.einsum("ij,ij->i", goal - a[bright], e) / np.einsum("ij,ij->i", e, e), 0, 1)
    gap = np.hypot(*(a[bright] + t[:, None] * e - goal).T)
    obstacle = int(world.segments_obstacle[bright[int(np.argmin(gap))]])
    faces = np.flatnonzero(world.segments_obstacle == obstacle)
    length = np.hypot(*(b[faces] - a[faces]).T)
    faces = faces[length >= length.max() * (1.0 - 1e-9)]
    # Each long face with both its normals; the room is where the ray runs farthest.
    d = b[faces] - a[faces]
    left = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(*d.T)[:, None]
    normals = np.concatenate([left, -left])
    centres = np.tile(0.5 * (a[faces] + b[faces]), (2, 1))
    hits = cast_rays(world, centres + 1e-6 * normals, normals, max_range_m=10.0)
    best = int(np.argmax(hits.distance_m))  # inf (nothing within 10 m) is the most room
    k = faces[best % faces.size]
    return DockingFace(np.stack([a[k], b[k]]), normals[best], obstacle)


def dock_pose(
    face: npt.ArrayLike, normal: npt.ArrayLike, dock_distance_m: float, head_offset_m: float
) -> tuple[float, float, float]:
    """The pose (x_m, y_m, yaw_rad) of ``base_link`` docked at a face.

    Parameters
    ----------
    face
        (2, 2) the face's end points, metres, world frame.
    normal
        (2,) its outward normal (normalised here).
    dock_distance_m
        The centre of scanning this far in front of the face's centre, metres.
    head_offset_m
        The centre of scanning this far ahead of ``base_link``, metres.
    """
    ends, n = _face(face, normal)
    base = ends.mean(axis=0) + (dock_distance_m + head_offset_m) * n
    return float(base[0]), float(base[1]), math.atan2(-float(n[1]), -float(n[0]))


def dock_error(
    true_pose: npt.ArrayLike,
    face: npt.ArrayLike,
    normal: npt.ArrayLike,
    dock_distance_m: float,
    head_offset_m: float,
) -> tuple[float, float]:
    """How far a pose is from docked at a face.

    Parameters
    ----------
    true_pose
        (3,) the vehicle's true ``(x_m, y_m, yaw_rad)``, world frame.
    face
        (2, 2) the face's end points, metres, world frame.
    normal
        (2,) its outward normal, toward the vehicle (normalised here).
    dock_distance_m
        The docking point lies this far in front of the face's centre, metres.
    head_offset_m
        The centre of scanning lies this far ahead of ``base_link``, metres.

    Returns
    -------
    (error_mm, error_deg)
        The distance of the centre of scanning from the docking point, millimetres; the
        angle between the heading and the face's inward normal ``−n``, degrees, in [0, 180].

    Raises
    ------
    ValueError
        For a pose, face or normal of the wrong shape or not finite, or a zero normal.
    """
    p = _pose(true_pose, "true_pose")
    ends, n = _face(face, normal)
    head = p[:2] + head_offset_m * np.array([math.cos(p[2]), math.sin(p[2])])
    target = ends.mean(axis=0) + dock_distance_m * n
    error_m = float(np.hypot(*(head - target)))
    error_rad = abs(_wrap(float(p[2]) - math.atan2(-float(n[1]), -float(n[0]))))
    return 1000.0 * error_m, math.degrees(error_rad)


def task_success(
    task: Task,
    true_pose: npt.ArrayLike,
    world: World | None = None,
    vehicle: VehicleSpec | None = None,
) -> bool:
    """Whether the vehicle, stopped at ``true_pose``, has done ``task`` (module docstring).

    Parameters
    ----------
    task
        The task.
    true_pose
        (3,) the vehicle's true ``(x_m, y_m, yaw_rad)``, world frame.
    world
        The true world: needed for dock (its docking face, :func:`docking_face`).
    vehicle
        The head's offset for dock (default :class:`VehicleSpec` ``()``).

    Raises
    ------
    ValueError
        For a bad pose, a dock task without a world, or a dock world without a target.
    """
    p = _pose(true_pose, "true_pose")
    if task.kind == "dock":
        if world is None:
            raise ValueError("task_success: a dock task needs the world (its docking face)")
        spec = vehicle if vehicle is not None else VehicleSpec()
        face = docking_face(world, task)
        error_mm, error_deg = dock_error(
            p, face.ends, face.normal, task.dock_distance_m, spec.head_offset_m
        )
        return error_mm <= 1000.0 * task.tolerance_m and error_deg <= math.degrees(
            DOCK_HEADING_TOLERANCE_RAD
        )
    reached = math.hypot(p[0] - task.goal[0], p[1] - task.goal[1]) <= task.tolerance_m
    if task.kind == "goto" or task.goal_yaw_rad is None:
        return reached
    return reached and abs(_wrap(float(p[2]) - task.goal_yaw_rad)) <= task.tolerance_rad


def normalised_score(
    success: bool,
    time_s: float,
    shortest_path_m: float,
    speed_m_s: float = REFERENCE_SPEED_M_S,
) -> float:
    """``success · T_ref / clip(T, 2·T_ref, 8·T_ref)``, ``T_ref = shortest_path_m / speed_m_s``.

    Parameters
    ----------
    success
        Whether the run succeeded.
    time_s
        ``T``: the run's time, seconds, >= 0.
    shortest_path_m
        The shortest path from start to goal, metres, > 0
        (:func:`agent.scoring.paths.reference_path`).
    speed_m_s
        The reference speed, m/s, > 0.

    Returns
    -------
    float
        In [1/8, 1/2] for a success, 0 for a failure.

    Raises
    ------
    ValueError
        For a negative or non-finite time, or a non-positive or non-finite path or speed.
    """
    if not (math.isfinite(time_s) and time_s >= 0.0):
        raise ValueError(f"time_s must be finite and >= 0, got {time_s!r}")
    if not (math.isfinite(shortest_path_m) and shortest_path_m > 0.0):
        raise ValueError(f"shortest_path_m must be positive and finite, got {shortest_path_m!r}")
    if not (math.isfinite(speed_m_s) and speed_m_s > 0.0):
        raise ValueError(f"speed_m_s must be positive and finite, got {speed_m_s!r}")
    t_ref = shortest_path_m / speed_m_s
    return float(success) * t_ref / float(np.clip(time_s, 2.0 * t_ref, 8.0 * t_ref))


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """The Wilson score interval on a success rate ``successes / n``.

    Parameters
    ----------
    successes
        Successful runs, 0 <= successes <= n.
    n
        Runs, >= 0.
    confidence
        The interval's confidence level, in (0, 1).

    Returns
    -------
    (low, high)
        Bounds on the rate, in [0, 1]; ``(nan, nan)`` for ``n = 0`` (no runs say nothing, and
        a summary over an empty group is not an error).

    Raises
    ------
    ValueError
        For counts out of range or a confidence outside (0, 1).
    """
    if int(n) != n or int(successes) != successes or not 0 <= successes <= n:
        raise ValueError(f"need integers 0 <= successes <= n, got successes={successes}, n={n}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if n == 0:
        return math.nan, math.nan
    # Imported here: scipy.stats costs a process about 0.7 s to import, and the closed
    # loop's workers import this module for task_success alone.
    from scipy.stats import binomtest

    ci = binomtest(int(successes), int(n)).proportion_ci(
        confidence_level=confidence, method="wilson"
    )
    return float(ci.low), float(ci.high)
