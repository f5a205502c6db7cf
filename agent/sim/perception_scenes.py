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
# Bend angles between the two faces' directions, rad: the benchmark's 10-20°.
BEND_ANGLE_RAD = (math.radians(10.0), math.radians(20.0))
# Angle between the beam to a grazing wall's centre and the wall, rad: the benchmark's 20-30°.
GRAZING_ANGLE_RAD = (math.radians(20.0), math.radians(30.0))
# Post radii of a fence, m (0.1-0.2 m across), and the gap between neighbouring posts'
# surfaces, m, where they do not touch: up to 2 cm (about 2.7 mm per sample at 1 m, so 0-4
# beams fall into a gap at 1.5-2.4 m), so the filter sees one continuous run. Half the
# gaps are 0: posts that touch.
FENCE_RADIUS_M = (0.05, 0.1)
FENCE_GAP_M = (0.0, 0.02)
FENCE_TOUCHING = 0.5
# Where the scenes are: half near (as the general mix), half far, at 1.5-2.4 m, where σ is
# large (8-20 mm) and a post or a short wall spans few samples.
NEAR_M = (0.7, 1.5)
FAR_M = (1.5, 2.4)
# A fence's row turned up to this far from square-on to the beam through its middle, rad:
# past about 0.6 rad neighbouring posts partly hide each other.
FENCE_TURN_RAD = 1.1


def _reflectivity(rng: np.random.Generator) -> float:
    return float(rng.uniform(0.3, 2.0))


def _distance(rng: np.random.Generator) -> float:
    """Half the scenes near (``NEAR_M``), half far (``FAR_M``), m."""
    return float(rng.uniform(*(FAR_M if rng.random() < 0.5 else NEAR_M)))


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
    """A short wall (0.2-0.5 m) seen at grazing incidence: 20-30° between the beam to its
    centre and the wall.

    The centre lies ahead within ±0.2 rad, half the walls at 0.7-1.5 m and half at 1.5-2.4 m
    (where the range noise, running nearly along the wall, is largest), the wall turned
    either way. Half of the scenes have a second wall behind it, square-on at 2.2-2.4 m
    (or just past the short wall's far end when that lies beyond), so that the short wall's
    run ends at an occluding edge as it often does in a room.
    """
    dist, bearing = _distance(rng), rng.uniform(-0.2, 0.2)
    cx, cy = dist * math.cos(bearing), dist * math.sin(bearing)
    graze = float(rng.uniform(*GRAZING_ANGLE_RAD)) * (1.0 if rng.random() < 0.5 else -1.0)
    heading = bearing + graze  # the wall's direction, graze from the beam's
    half = 0.5 * rng.uniform(0.2, 0.5)
    dx, dy = half * math.cos(heading), half * math.sin(heading)
    walls = [(((cx - dx, cy - dy), (cx + dx, cy + dy)), _reflectivity(rng))]
    if rng.random() < 0.5:
        back = max(rng.uniform(2.2, 2.4), cx + abs(dx) + 0.1)
        walls.append((((back, -1.2), (back, 1.2)), _reflectivity(rng)))
    return World.build(walls=walls, name="grazing")


def fence_scene(rng: np.random.Generator) -> World:
    """A row of 3-7 round posts, 0.1-0.2 m across, touching or nearly touching.

    One nominal radius per fence (each post within ±5 % of it); between neighbouring posts'
    surfaces 0 (touching, ``FENCE_TOUCHING`` of the gaps) or up to 2 cm; the row's middle
    ahead within ±0.15 rad, half the fences at 0.7-1.5 m and half at 1.5-2.4 m, the row
    turned up to ±``FENCE_TURN_RAD`` from square-on, so that in oblique rows the posts
    partly hide each other. Half the fences share one reflectivity (one paint); in the
    others each post has its own (posts replaced, weathered or of mixed materials).
    """
    count = int(rng.integers(3, 8))
    radius = float(rng.uniform(*FENCE_RADIUS_M))
    radii = radius * rng.uniform(0.95, 1.05, count)
    gaps = np.where(
        rng.random(count - 1) < FENCE_TOUCHING, 0.0, rng.uniform(*FENCE_GAP_M, count - 1)
    )
    dist, bearing = _distance(rng), rng.uniform(-0.15, 0.15)
    heading = bearing + 0.5 * math.pi + rng.uniform(-FENCE_TURN_RAD, FENCE_TURN_RAD)
    # Positions along the row: each post's centre one radius past the previous post's
    # surface and the gap.
    along = np.concatenate([[0.0], np.cumsum(radii[:-1] + gaps + radii[1:])])
    along -= 0.5 * along[-1]
    mx, my = dist * math.cos(bearing), dist * math.sin(bearing)
    one_paint = rng.random() < 0.5
    paint = _reflectivity(rng)
    reflectivities = [paint if one_paint else _reflectivity(rng) for _ in range(count)]
    cylinders = [
        ((mx + s * math.cos(heading), my + s * math.sin(heading)), float(r), refl)
        for s, r, refl in zip(along.tolist(), radii.tolist(), reflectivities, strict=True)
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
