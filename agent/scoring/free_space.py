"""Scoring a free-space profile against the true world, movers included.

A profile claims, for each bearing (``base_link`` axes at its stamp, about the centre of
scanning ``mount_offset_m`` ahead of ``base_link``), a distance known clear (0: unknown).
The truth along that bearing is the distance to the first surface of the world, static
obstacles and movers where they are at the stamp, cast from the vehicle's *true* centre of
scanning along the true heading plus the bearing (:func:`agent.sim.raycast.cast_rays` for
the static world, a ray-circle intersection for the movers).

* A claim is **false** when it reaches farther than that surface by more than
  ``tolerance_m`` (1 cm by default: half the free-space grid's 5 cm cell would hide real
  errors, and the profile is built to stay short of hits by a margin of several σ).
* A profile taken while a mover overlaps the vehicle's footprint (a collision: the movers
  walk their paths blindly and the benchmark's scripted driver does not avoid them) is not
  scored but counted (``in_collision``): the profile takes the vehicle's own body as clear,
  nothing can be there but the vehicle, and with a mover inside it every bearing through it
  is "false" (measured on ``bench tracking``, 8 scenes: 367 of 393 false bearings on
  ``sweep``, all 64 on ``forward``, were such).
* **Coverage** compares the claimed distances with the truly clear ones, both capped at the
  sensor's reach: ``Σ min(claim, reach) / Σ min(true, reach)`` over every bearing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from agent.arrays import FloatArray
from agent.sim.raycast import cast_rays, ray_directions
from agent.sim.world import World

__all__ = ["FreeSpaceScore", "score_profile", "true_clear_range"]


def _circle_hits(
    origin: FloatArray, directions: FloatArray, centre: FloatArray, radius: FloatArray
) -> FloatArray:
    """(b,) distance along unit rays from one origin to the first of the circles (inf: none;
    0 when the origin is inside one)."""
    if centre.shape[0] == 0:
        return np.full(directions.shape[0], np.inf)
    rel = centre - origin  # (m, 2)
    along = directions @ rel.T  # (b, m): projection of each centre on each ray
    closest2 = np.einsum("mj,mj->m", rel, rel)[None] - along**2
    half = np.sqrt(np.maximum(radius[None] ** 2 - closest2, 0.0))
    enter = along - half
    inside = np.einsum("mj,mj->m", rel, rel)[None] <= radius[None] ** 2
    crosses = (closest2 <= radius[None] ** 2) & (along + half >= 0.0)
    dist = np.where(inside, 0.0, np.where(crosses & (enter >= 0.0), enter, np.inf))
    return np.asarray(dist.min(axis=1), dtype=np.float64)


def true_clear_range(
    world: World,
    mover_xy: FloatArray,
    mover_radius_m: FloatArray,
    origin_xy: FloatArray,
    headings_rad: FloatArray,
) -> FloatArray:
    """(b,) distance from ``origin_xy`` (world frame) along each heading to the first true
    surface, static or moving, metres; inf where nothing is hit."""
    static, moving = _clear_ranges(world, mover_xy, mover_radius_m, origin_xy, headings_rad)
    return np.asarray(np.minimum(static, moving), dtype=np.float64)


def _overlaps(
    centres: FloatArray,
    radii: FloatArray,
    pose: tuple[float, float, float],
    footprint_m: tuple[float, float],
) -> bool:
    """Whether any circle overlaps the rectangle ``footprint_m`` (length, width) centred on
    ``pose`` (x, y, yaw) and aligned with it."""
    if centres.shape[0] == 0:
        return False
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    rel = centres - np.array([x, y])
    local = np.stack([rel[:, 0] * c + rel[:, 1] * s, -rel[:, 0] * s + rel[:, 1] * c], axis=1)
    half = 0.5 * np.asarray(footprint_m, dtype=np.float64)
    outside = np.maximum(np.abs(local) - half, 0.0)
    return bool(np.any(np.hypot(outside[:, 0], outside[:, 1]) < radii))


def _clear_ranges(
    world: World,
    mover_xy: FloatArray,
    mover_radius_m: FloatArray,
    origin_xy: FloatArray,
    headings_rad: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """The distances of :func:`true_clear_range` to the static world and to the movers."""
    directions = ray_directions(headings_rad)
    static = np.asarray(cast_rays(world, origin_xy, directions).distance_m, dtype=np.float64)
    moving = _circle_hits(
        origin_xy, directions, np.asarray(mover_xy).reshape(-1, 2), np.asarray(mover_radius_m)
    )
    return static, moving


@dataclass
class FreeSpaceScore:
    """Claims and errors summed over profiles (module docstring)."""

    claimed: int = 0
    false: int = 0
    false_at_mover: int = 0  # of ``false``: the first true surface was a mover
    claimed_m: float = 0.0
    true_clear_m: float = 0.0
    profiles: int = 0
    in_collision: int = 0  # profiles not scored: a mover overlapped the vehicle

    @property
    def false_free_rate(self) -> float | None:
        return self.false / self.claimed if self.claimed else None

    @property
    def coverage(self) -> float | None:
        return self.claimed_m / self.true_clear_m if self.true_clear_m > 0.0 else None


def score_profile(
    score: FreeSpaceScore,
    world: World,
    mover_xy: npt.ArrayLike,
    mover_radius_m: npt.ArrayLike,
    true_pose: npt.ArrayLike,
    bearing_rad: npt.ArrayLike,
    free_range_m: npt.ArrayLike,
    mount_offset_m: float = 0.30,
    reach_m: float = 2.5,
    tolerance_m: float = 0.01,
    footprint_m: tuple[float, float] = (0.8, 0.6),
) -> FloatArray:
    """Add one profile to ``score``; returns the true clear range per bearing, (b,).

    ``true_pose`` (x, y, yaw) of ``base_link`` in the world at the profile's stamp;
    ``mover_xy`` (m, 2) and ``mover_radius_m`` (m,) the movers then; ``footprint_m``
    (length, width) of the vehicle, centred on ``base_link``. A profile in collision with
    a mover (module docstring) is counted in ``score.in_collision`` and not scored.
    """
    x, y, yaw = (float(v) for v in np.asarray(true_pose, dtype=np.float64))
    bearings = np.asarray(bearing_rad, dtype=np.float64).reshape(-1)
    claim = np.asarray(free_range_m, dtype=np.float64).reshape(-1)
    if bearings.shape != claim.shape:
        raise ValueError(f"bearings {bearings.shape} and ranges {claim.shape} differ")
    origin = np.array([x + mount_offset_m * math.cos(yaw), y + mount_offset_m * math.sin(yaw)])
    static, moving = _clear_ranges(
        world,
        np.asarray(mover_xy, dtype=np.float64).reshape(-1, 2),
        np.asarray(mover_radius_m, dtype=np.float64).reshape(-1),
        origin,
        yaw + bearings,
    )
    truth = np.minimum(static, moving)
    if _overlaps(np.asarray(mover_xy, dtype=np.float64).reshape(-1, 2),
                 np.asarray(mover_radius_m, dtype=np.float64).reshape(-1),
                 (x, y, yaw), footprint_m):  # fmt: skip
        score.in_collision += 1
        return truth
    claimed = claim > 0.0
    false = claimed & (claim > truth + tolerance_m)
    score.profiles += 1
    score.claimed += int(claimed.sum())
    score.false += int(false.sum())
    score.false_at_mover += int(np.sum(false & (moving < static)))
    score.claimed_m += float(np.minimum(claim, reach_m).sum())
    score.true_clear_m += float(np.minimum(truth, reach_m).sum())
    return truth
