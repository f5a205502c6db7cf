"""Helpers shared by the world, world-file and ray-casting tests."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import numpy.typing as npt

from agent.errors import WorldFileError
from agent.sim.movers import Mover
from agent.sim.raycast import cast_rays, ray_directions
from agent.sim.world import World, world_from_obstacles

REPO = Path(__file__).resolve().parents[3]
EXAMPLE_WORLDS = REPO / "worlds"
TEST_WORLDS = REPO / "tests" / "data" / "worlds"

FloatArray = npt.NDArray[np.float64]


def one_ray(
    world: World,
    origin: tuple[float, float],
    heading_rad: float,
    **kwargs: float,
) -> tuple[float, FloatArray, float, int]:
    """Cast a single ray; return (distance, normal, reflectivity, obstacle)."""
    hits = cast_rays(world, np.array(origin), ray_directions(np.array([heading_rad])), **kwargs)
    return (
        float(hits.distance_m[0]),
        hits.normal[0],
        float(hits.reflectivity[0]),
        int(hits.obstacle[0]),
    )


def random_world(rng: np.random.Generator, n_walls: int, n_boxes: int, n_cyl: int) -> World:
    """Random walls (random walks of 2-5 points), boxes and cylinders in a 12 m square."""
    walls = []
    for _ in range(n_walls):
        steps = rng.uniform(-1.0, 1.0, (int(rng.integers(2, 6)), 2))
        points = np.cumsum(steps, axis=0) + rng.uniform(-6.0, 6.0, 2)
        walls.append((points, float(rng.uniform(0.2, 3.0))))
    boxes = [
        (rng.uniform(-6.0, 6.0, 2), rng.uniform(0.1, 1.0, 2), float(rng.uniform(-3.0, 3.0)), 1.0)
        for _ in range(n_boxes)
    ]
    cylinders = [
        (rng.uniform(-6.0, 6.0, 2), float(rng.uniform(0.05, 0.5)), float(rng.uniform(0.2, 2.0)))
        for _ in range(n_cyl)
    ]
    return world_from_obstacles(walls, boxes, cylinders)


def check_single_line_error(exc: WorldFileError, path: Path | None, *fragments: str) -> None:
    text = str(exc)
    assert "\n" not in text and "\r" not in text
    prefix = "world: " if path is None else f"world file {path}: "
    assert text.startswith(prefix), text
    for fragment in fragments:
        assert fragment in text, text


def closest_bodies(movers: Sequence[Mover], horizon_s: float = 300.0) -> float:
    """Least surface-to-surface distance between any two movers over ``horizon_s``, at
    5 ms (independent of ``walks_apart``'s own 10 ms grid); inf for fewer than two."""
    t = np.arange(0.0, horizon_s, 0.005)
    least = math.inf
    for i, a in enumerate(movers):
        for b in movers[i + 1 :]:
            gap = np.hypot(*(a.states(t)[0] - b.states(t)[0]).T) - a.radius_m - b.radius_m
            least = min(least, float(gap.min()))
    return least
