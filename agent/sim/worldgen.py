"""Random worlds for benchmarks and Monte-Carlo evaluation."""

from __future__ import annotations

import math

import numpy as np

from agent.sim.world import World


def random_world(
    rng: np.random.Generator,
    n_obstacles: int = 50,
    room_m: float = 12.0,
    clear_radius_m: float = 1.0,
) -> World:
    """A square room with ``n_obstacles`` boxes and cylinders scattered in it.

    The room's four walls count as one obstacle; the rest are about two boxes for every
    cylinder, 0.1-0.8 m across, reflectivity 0.3-2.0, kept ``clear_radius_m`` away from the
    vehicle, which stands at the centre of the room at a random heading.
    """
    if n_obstacles < 1:
        raise ValueError(f"n_obstacles must be at least 1, got {n_obstacles}")
    half = 0.5 * room_m
    room = ((-half, -half), (half, -half), (half, half), (-half, half), (-half, -half))
    boxes, cylinders = [], []
    for _ in range(n_obstacles - 1):
        while True:
            centre = rng.uniform(-half + 0.5, half - 0.5, 2)
            if np.hypot(*centre) > clear_radius_m + 0.6:
                break
        reflectivity = float(rng.uniform(0.3, 2.0))
        if rng.random() < 2 / 3:
            size = rng.uniform(0.1, 0.8, 2)
            boxes.append((tuple(centre), tuple(size), float(rng.uniform(0, math.pi)), reflectivity))
        else:
            cylinders.append((tuple(centre), float(rng.uniform(0.05, 0.4)), reflectivity))
    return World.build(
        walls=[(room, 1.0)],
        boxes=boxes,
        cylinders=cylinders,
        vehicle_pose=(0.0, 0.0, float(rng.uniform(-math.pi, math.pi))),
        name=f"random {n_obstacles} obstacles",
    )


def perception_scene(rng: np.random.Generator) -> World:
    """A scene for the perception bench, around a centre of scanning at the origin facing +x.

    One or two walls at 0.6-2.4 m up to 57° from square-on, up to two boxes (0.1-0.5 m sides)
    and up to two cylinders (radius 0.05-0.3 m) at 0.6-2 m, reflectivity 0.3-2.0.
    """
    walls: list[tuple[object, float]] = []
    boxes: list[tuple[object, object, float, float]] = []
    cylinders: list[tuple[object, float, float]] = []
    for _ in range(int(rng.integers(1, 3))):
        bearing, dist = rng.uniform(-0.3, 0.3), rng.uniform(0.6, 2.4)
        tilt = bearing + rng.uniform(-1.0, 1.0)
        cx, cy = dist * math.cos(bearing), dist * math.sin(bearing)
        dx, dy = -math.sin(tilt), math.cos(tilt)
        walls.append(
            (((cx - 2 * dx, cy - 2 * dy), (cx + 2 * dx, cy + 2 * dy)), float(rng.uniform(0.3, 2.0)))
        )
    for _ in range(int(rng.integers(0, 3))):
        d, b = rng.uniform(0.6, 2.0), rng.uniform(-0.35, 0.35)
        boxes.append(
            (
                (d * math.cos(b), d * math.sin(b)),
                tuple(rng.uniform(0.1, 0.5, 2)),
                float(rng.uniform(0, math.pi)),
                float(rng.uniform(0.3, 2.0)),
            )
        )
    for _ in range(int(rng.integers(0, 3))):
        d, b = rng.uniform(0.6, 2.0), rng.uniform(-0.35, 0.35)
        cylinders.append(
            (
                (d * math.cos(b), d * math.sin(b)),
                float(rng.uniform(0.05, 0.3)),
                float(rng.uniform(0.3, 2.0)),
            )
        )
    return World.build(walls=walls, boxes=boxes, cylinders=cylinders)  # type: ignore[arg-type]
