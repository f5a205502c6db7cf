"""Ray casting against a :class:`~agent.sim.world.World`: first hits and line of sight.

:func:`cast_rays` finds the first surface each ray meets; :func:`segment_clear` is the
line-of-sight test (does a straight path cross any obstacle). Both check their arguments here
and run the compiled loop of :mod:`agent.sim.raycast_kernels`, one pass per ray over the
world's segments and circles. Frames follow REP-103 (x forward, y left, angles
counter-clockwise); radians and metres, world frame. Hits name obstacles by their
:attr:`~agent.sim.world.Obstacle.id`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from agent.arrays import BoolArray, FloatArray
from agent.sim import raycast_kernels
from agent.sim.world import World

__all__ = ["RayHits", "cast_rays", "ray_directions", "segment_clear", "warm_up", "world_tables"]

IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class RayHits:
    """The first surface each ray meets. Arrays are read-only.

    Attributes
    ----------
    distance_m
        (n,) float64: distance along the ray to the hit, metres; ``inf`` where nothing is hit.
    normal
        (n, 2) float64: unit surface normal at the hit, world frame, turned back toward the
        ray (``dot(normal, direction) <= 0``); NaN where nothing is hit.
    reflectivity
        (n,) float64: reflectivity of the surface hit; NaN where nothing is hit.
    obstacle
        (n,) int64: :attr:`~agent.sim.world.Obstacle.id` of the obstacle hit; -1 where nothing
        is hit.
    """

    distance_m: FloatArray
    normal: FloatArray
    reflectivity: FloatArray
    obstacle: IntArray

    @property
    def hit(self) -> BoolArray:
        """(n,) bool: True where the ray hit something."""
        return np.isfinite(self.distance_m)


def ray_directions(headings_rad: npt.ArrayLike) -> FloatArray:
    """Unit direction vectors for headings.

    Parameters
    ----------
    headings_rad
        (...) headings in radians, counter-clockwise from +x.

    Returns
    -------
    numpy.ndarray
        (..., 2) float64 ``[cos, sin]``.
    """
    h = np.asarray(headings_rad, dtype=np.float64)
    return np.stack([np.cos(h), np.sin(h)], axis=-1)


def _rays(origins: npt.ArrayLike, directions: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Check rays; return origins (n, 2) or (1, 2) and unit directions (n, 2)."""
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    if o.ndim not in (1, 2) or o.shape[-1] != 2 or d.ndim not in (1, 2) or d.shape[-1] != 2:
        raise ValueError(f"origins and directions must be (n, 2) or (2,), got {o.shape}, {d.shape}")
    o2, d2 = np.atleast_2d(o), np.atleast_2d(d)
    n = max(o2.shape[0], d2.shape[0])
    if o2.shape[0] not in (1, n) or d2.shape[0] not in (1, n):
        raise ValueError(f"origins {o.shape} and directions {d.shape} do not match")
    if not (np.all(np.isfinite(o2)) and np.all(np.isfinite(d2))):
        raise ValueError("origins and directions must be finite")
    norm = np.hypot(d2[:, 0], d2[:, 1])
    if np.any(norm == 0.0):
        raise ValueError("directions must not be zero vectors")
    return o2, np.broadcast_to(d2 / norm[:, None], (n, 2))


def _range_bounds(min_range_m: float, max_range_m: float) -> None:
    if not (math.isfinite(min_range_m) and min_range_m >= 0.0):
        raise ValueError(f"min_range_m must be finite and >= 0, got {min_range_m!r}")
    if not max_range_m > min_range_m:
        raise ValueError(f"max_range_m must be > min_range_m, got {max_range_m!r}")


def world_tables(world: World) -> tuple[FloatArray, FloatArray]:
    """The world's segments (m, 12) and circles (k, 5) as the compiled loops read them (see
    :func:`agent.sim.raycast_kernels.pack_world`)."""
    return raycast_kernels.pack_world(
        world.segments_start, world.segments_end, world.segments_reflectivity,
        world.segments_obstacle, world.circles_center, world.circles_radius,
        world.circles_reflectivity, world.circles_obstacle,
    )  # fmt: skip


def _writable(arr: FloatArray) -> FloatArray:
    """A C-ordered, writable copy: the compiled loops then see one array type whatever the
    caller passed (read-only and broadcast arrays would each need a compilation of their own)."""
    return np.array(arr, dtype=np.float64, order="C")


def _read_only(*arrays: npt.NDArray[Any]) -> None:
    for arr in arrays:
        arr.flags.writeable = False


def cast_rays(
    world: World,
    origins: npt.ArrayLike,
    directions: npt.ArrayLike,
    max_range_m: float = math.inf,
    min_range_m: float = 0.0,
) -> RayHits:
    """Find the first surface each ray meets.

    Parameters
    ----------
    world
        The obstacles (cull with :meth:`World.nearby` first for large worlds).
    origins
        (n, 2) or (2,) ray origins, world frame, metres.
    directions
        (n, 2) or (2,) ray directions, world frame; normalised here (see
        :func:`ray_directions` to make them from headings).
    max_range_m
        Hits farther than this are ignored (inclusive bound), metres.
    min_range_m
        Hits at or nearer than this are ignored (exclusive bound), metres, >= 0.

    Returns
    -------
    RayHits
        One entry per ray, ``n = max(len(origins), len(directions))``. A ray that starts inside
        a cylinder or box meets its wall from inside; its normal still points back at the ray.
        Rays parallel to a segment do not hit it.
    """
    _range_bounds(min_range_m, max_range_m)
    P, D = _rays(origins, directions)
    distance, normal, refl, obstacle = raycast_kernels.cast(
        _writable(P), _writable(D), float(min_range_m), float(max_range_m), *world_tables(world)
    )
    _read_only(distance, normal, refl, obstacle)
    return RayHits(distance_m=distance, normal=normal, reflectivity=refl, obstacle=obstacle)


def segment_clear(
    world: World, start: npt.ArrayLike, end: npt.ArrayLike, margin_m: float = 1e-6
) -> BoolArray:
    """Whether straight paths cross no obstacle (a line-of-sight test).

    Parameters
    ----------
    world
        The obstacles.
    start, end
        (n, 2) or (2,) path ends, world frame, metres.
    margin_m
        Surfaces within this distance (metres, >= 0) of either end are ignored, so a path that
        ends exactly on a surface (a laser spot) counts as clear.

    Returns
    -------
    numpy.ndarray
        (n,) bool: True where the path is clear. Paths no longer than ``2 * margin_m`` are clear.
    """
    if not (math.isfinite(margin_m) and margin_m >= 0.0):
        raise ValueError(f"margin_m must be finite and >= 0, got {margin_m!r}")
    s = np.atleast_2d(np.asarray(start, dtype=np.float64))
    e = np.atleast_2d(np.asarray(end, dtype=np.float64))
    if s.ndim != 2 or s.shape[1] != 2 or e.ndim != 2 or e.shape[1] != 2:
        raise ValueError(f"start and end must be (n, 2) or (2,), got {s.shape}, {e.shape}")
    s, e = np.broadcast_arrays(s, e)
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(e))):
        raise ValueError("start and end must be finite")
    return raycast_kernels.clear_paths(
        _writable(s), _writable(e), float(margin_m), *world_tables(world)
    )


def warm_up() -> None:
    """Load the compiled ray caster (compiling it on the first use on this machine)."""
    world = World.build(
        walls=[(((1.0, -1.0), (1.0, 1.0)), 1.0)], cylinders=[((0.5, 0.5), 0.1, 1.0)]
    )
    cast_rays(world, np.zeros(2), ray_directions(np.linspace(-0.5, 0.5, 3)))
    segment_clear(world, np.zeros((2, 2)), np.ones((2, 2)))
