"""Scenes for the perception benchmark: the general mix, and three classes that test what it
draws too rarely.

All are built around a centre of scanning at the world origin facing +x (the pose of
:func:`agent.sim.targets.head_centred_pose`), within the ±20° window and the 0.4-2.5 m depth
of field:

* ``random``: :func:`agent.sim.worldgen.perception_scene` (walls, boxes, cylinders);
* ``bend``: :func:`bend_scene`, one wall of two faces meeting at a shallow angle (10-20°),
  which one line across both fits nearly as well as two;
* ``grazing``: :func:`grazing_scene`, a short wall seen at grazing incidence (20-30°
  between beam and wall), where range noise runs nearly along the wall;
* ``fence``: :func:`fence_scene`, a row of round posts (0.1-0.2 m across) that touch or
  nearly touch, so that one range-continuous run holds several cylinders.

Each generator takes its randomness from the generator it is given only, so a scene set is
reproducible from a seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from agent.sim.world import World
from agent.sim.worldgen import perception_scene

SceneClass = str
# Bend angles between the two faces' directions, rad: the issue's 10-20°.
BEND_ANGLE_RAD = (math.radians(10.0), math.radians(20.0))
# Angle between the beam to a grazing wall's centre and the wall, rad: the 20-30°.
GRAZING_ANGLE_RAD = (math.radians(20.0), math.radians(30.0))
# Post radii of a fence, m (0.1-0.2 m across), and the gap between neighbouring posts'
# surfaces, m: 0 (touching) to 2 cm, less than one beam spacing at 1.5 m (about 2.7 mm per
# sample at 1 m, so 0-4 beams fall into a gap), so the filter sees one continuous run.
FENCE_RADIUS_M = (0.05, 0.1)
FENCE_GAP_M = (0.0, 0.02)


def _reflectivity(rng: np.random.Generator) -> float:
    return float(rng.uniform(0.3, 2.0))


def bend_scene(rng: np.random.Generator) -> World:
    """One wall of two straight faces meeting at 10-20°, the bend toward or away from the
    sensor.

    The bend lies 0.8-2.0 m ahead within ±0.15 rad; the faces are 0.4-1.0 m long, the first
    turned up to ±0.5 rad from square-on to the beam through the bend, the second turned
    from it by the bend angle either way. One reflectivity for the wall (a painted wall
    turning a corner): its intensities do not give the bend away, its ranges must.
    """
    dist, bearing = rng.uniform(0.8, 2.0), rng.uniform(-0.15, 0.15)
    vx, vy = dist * math.cos(bearing), dist * math.sin(bearing)
    heading = bearing + 0.5 * math.pi + rng.uniform(-0.5, 0.5)  # the first face's direction
    bend = float(rng.uniform(*BEND_ANGLE_RAD)) * (1.0 if rng.random() < 0.5 else -1.0)
    la, lb = rng.uniform(0.4, 1.0, 2)
    a = (vx - la * math.cos(heading), vy - la * math.sin(heading))
    b = (vx + lb * math.cos(heading + bend), vy + lb * math.sin(heading + bend))
    return World.build(walls=[((a, (vx, vy), b), _reflectivity(rng))], name="bend")


def grazing_scene(rng: np.random.Generator) -> World:
    """A short wall (0.25-0.6 m) seen at grazing incidence: 20-30° between the beam to its
    centre and the wall.

    The centre lies 0.8-2.0 m ahead within ±0.2 rad, the wall turned either way. Half of
    the scenes have a second wall behind it, square-on at 2.2-2.4 m, so that the short
    wall's run ends at an occluding edge as it often does in a room.
    """
    dist, bearing = rng.uniform(0.8, 2.0), rng.uniform(-0.2, 0.2)
    cx, cy = dist * math.cos(bearing), dist * math.sin(bearing)
    graze = float(rng.uniform(*GRAZING_ANGLE_RAD)) * (1.0 if rng.random() < 0.5 else -1.0)
    heading = bearing + graze  # the wall's direction, graze from the beam's
    half = 0.5 * rng.uniform(0.25, 0.6)
    dx, dy = half * math.cos(heading), half * math.sin(heading)
    walls = [(((cx - dx, cy - dy), (cx + dx, cy + dy)), _reflectivity(rng))]
    if rng.random() < 0.5:
        back = rng.uniform(2.2, 2.4)
        walls.append((((back, -1.2), (back, 1.2)), _reflectivity(rng)))
    return World.build(walls=walls, name="grazing")


def fence_scene(rng: np.random.Generator) -> World:
    """A row of 3-7 round posts, 0.1-0.2 m across, touching or nearly touching.

    One nominal radius per fence (each post within ±5 % of it), 0-2 cm between neighbouring
    posts' surfaces; the row's middle 0.7-1.8 m ahead within ±0.15 rad, the row turned up to
    ±0.6 rad from square-on. Posts share one reflectivity (one fence, one paint).
    """
    count = int(rng.integers(3, 8))
    radius = float(rng.uniform(*FENCE_RADIUS_M))
    radii = radius * rng.uniform(0.95, 1.05, count)
    gaps = rng.uniform(*FENCE_GAP_M, count - 1)
    dist, bearing = rng.uniform(0.7, 1.8), rng.uniform(-0.15, 0.15)
    heading = bearing + 0.5 * math.pi + rng.uniform(-0.6, 0.6)  # along the row
    # Positions along the row: each post's centre one radius past the previous post's
    # surface and the gap.
    along = np.concatenate([[0.0], np.cumsum(radii[:-1] + gaps + radii[1:])])
    along -= 0.5 * along[-1]
    mx, my = dist * math.cos(bearing), dist * math.sin(bearing)
    reflectivity = _reflectivity(rng)
    cylinders = [
        ((mx + s * math.cos(heading), my + s * math.sin(heading)), float(r), reflectivity)
        for s, r in zip(along.tolist(), radii.tolist(), strict=True)
    ]
    return World.build(cylinders=cylinders, name="fence")


SCENES: dict[SceneClass, Callable[[np.random.Generator], World]] = {
    "random": perception_scene,
    "bend": bend_scene,
    "grazing": grazing_scene,
    "fence": fence_scene,
}
# The benchmark's cycle of classes: every other scene the general mix, the rest the three
# targeted classes in turn (each a sixth of the scenes).
BENCH_CYCLE: tuple[SceneClass, ...] = ("random", "bend", "random", "grazing", "random", "fence")


def scene_class(index: int) -> SceneClass:
    """The class of the benchmark's scene number ``index`` (see ``BENCH_CYCLE``)."""
    return BENCH_CYCLE[index % len(BENCH_CYCLE)]
