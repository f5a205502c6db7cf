"""Random worlds for benchmarks and Monte-Carlo evaluation.

Every generator draws only from the ``rng`` it is given, in a fixed order, so the same
generator state gives the same world. Movers (:mod:`agent.sim.movers`) walk blindly: their
paths may pass through static obstacles and the vehicle, as a scripted walker's would.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from agent.arrays import FloatArray
from agent.sim.movers import Mover, walks_apart
from agent.sim.world import World

__all__ = ["perception_scene", "random_world", "tracking_scene"]


def random_world(
    rng: np.random.Generator,
    n_obstacles: int = 50,
    room_m: float = 12.0,
    clear_radius_m: float = 1.0,
    n_movers: int = 0,
    mover_speed_m_s: tuple[float, float] = (0.2, 0.8),
) -> World:
    """A square room with ``n_obstacles`` boxes and cylinders scattered in it.

    The room's four walls count as one obstacle; the rest are about two boxes for every
    cylinder, 0.1-0.8 m across, reflectivity 0.3-2.0, kept ``clear_radius_m`` away from the
    vehicle, which stands at the centre of the room at a random heading.

    ``n_movers`` movers (radius 0.1-0.3 m, reflectivity 0.3-2.0, speed uniform in
    ``mover_speed_m_s``) walk straight paths of 2-6 m inside the room, each passing within
    3 m of the vehicle, never within :data:`agent.sim.movers.MOVER_GAP_M` of one another
    (redrawn, at most 50 times each, then dropped). They are drawn after everything else,
    so a world drawn with ``n_movers=0`` is the world this function drew before it had
    movers.
    """
    if n_obstacles < 1:
        raise ValueError(f"n_obstacles must be at least 1, got {n_obstacles}")
    if n_movers < 0:
        raise ValueError(f"n_movers must be >= 0, got {n_movers}")
    lo_speed, hi_speed = (float(v) for v in mover_speed_m_s)
    if not 0.0 <= lo_speed <= hi_speed <= 3.0:
        raise ValueError(
            f"mover_speed_m_s must be (lo, hi) with 0 <= lo <= hi <= 3, got {mover_speed_m_s!r}"
        )
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
    vehicle_yaw = float(rng.uniform(-math.pi, math.pi))
    movers: list[Mover] = []
    inner = half - 0.5
    for _ in range(n_movers):
        for _attempt in range(50):
            mid = rng.uniform(-min(3.0, inner), min(3.0, inner), 2)
            heading = rng.uniform(-math.pi, math.pi)
            length = rng.uniform(2.0, 6.0)
            offset = 0.5 * length * np.array([math.cos(heading), math.sin(heading)])
            path = np.clip(np.stack([mid - offset, mid + offset]), -inner, inner)
            mover = Mover(
                radius_m=float(rng.uniform(0.1, 0.3)),
                reflectivity=float(rng.uniform(0.3, 2.0)),
                path=path,
                speed_m_s=float(rng.uniform(lo_speed, hi_speed)),
            )
            if walks_apart(movers, mover):
                movers.append(mover)
                break
    name = f"random {n_obstacles} obstacles"
    return World.build(
        walls=[(room, 1.0)],
        boxes=boxes,
        cylinders=cylinders,
        vehicle_pose=(0.0, 0.0, vehicle_yaw),
        name=name if not movers else f"{name}, {len(movers)} movers",
        movers=movers,
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


TRACKING_CLEARANCE_M = 0.7
"""Least distance from a tracking scene's vehicle path to any static obstacle, metres: half
the vehicle's 0.6 m width plus 0.4 m, the sensor's nearest range, so that what lines the
path can be seen from it."""
TRACKING_SCENE_S = 60.0
"""How long a tracking scene's movers are kept apart (:func:`agent.sim.movers.walks_apart`),
seconds: ``bench tracking`` drives the path at 0.4 m/s for 20-40 s and cuts a scene at 60."""
MOVER_CLEARANCE_M = 0.1
"""Least distance from a mover's surface to any static obstacle along its walk, metres:
people walk round pillars, not through them (nor through one another:
:data:`agent.sim.movers.MOVER_GAP_M`)."""


def tracking_scene(
    rng: np.random.Generator, n_movers: int | None = None
) -> tuple[World, FloatArray]:
    """A random dynamic scene and the path a vehicle drives through it (tracking benches).

    The path starts at the origin at a random heading and runs 8-15 m over 2-4 straight legs
    (each at least 1.5 m) with turns of up to 60° between them. Static obstacles line it:

    * a rectangular room around everything, at least 1.5 m beyond the path;
    * 1-2 walls of 1.5-4 m beside and parallel to a leg, 0.9-2.2 m to one side;
    * 4-9 boxes (sides 0.15-0.6 m) and cylinders (radius 0.05-0.3 m) beside the path, their
      near surface 0.75-2.0 m from the path point they were placed by, so that the sensor
      (0.4-2.5 m) has them in range as the vehicle passes;

    none nearer than :data:`TRACKING_CLEARANCE_M` to the path (candidates that would be are
    redrawn, at most 50 times each, then dropped), nor within 0.1 m of one another.
    ``n_movers`` movers (default: 0-3, drawn) of radius 0.15-0.3 m walk at 0.2-0.8 m/s
    back and forth along straight paths of 2-5 m that cross the vehicle's path at 45-135°
    somewhere in its middle 80 %, never within :data:`MOVER_CLEARANCE_M` of a static
    obstacle, nor within :data:`agent.sim.movers.MOVER_GAP_M` of another mover for
    :data:`TRACKING_SCENE_S` (:func:`agent.sim.movers.walks_apart`)
    (walks that would be are redrawn, at most 50 times each, then dropped; the
    world's name counts the movers kept). Reflectivities are 0.3-2.0 (walls 0.5-1.5).

    Returns
    -------
    world, path
        The world (its ``vehicle_pose`` is the path's start, facing along the first leg) and
        the path as (k, 2) waypoints in the world frame, metres, the first one the start.
    """
    if n_movers is not None and not 0 <= n_movers <= 64:
        raise ValueError(f"n_movers must be from 0 to 64, got {n_movers}")
    n_movers = int(rng.integers(0, 4)) if n_movers is None else n_movers

    # The path: legs of at least 1.5 m adding up to 8-15 m.
    n_legs = int(rng.integers(2, 5))
    total = rng.uniform(8.0, 15.0)
    legs = 1.5 + rng.dirichlet(np.ones(n_legs)) * (total - 1.5 * n_legs)
    headings = rng.uniform(-math.pi, math.pi) + np.concatenate(
        [[0.0], np.cumsum(rng.uniform(-math.pi / 3, math.pi / 3, n_legs - 1))]
    )
    steps = legs[:, None] * np.stack([np.cos(headings), np.sin(headings)], axis=1)
    path = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    samples = _path_samples(path, 0.02)

    placed: list[tuple[FloatArray, float]] = []  # bounding circles of what is placed

    def fits(centre: FloatArray, radius: float, surface_gap: FloatArray) -> bool:
        """Clear of the path (``surface_gap``: distances from the path samples to the
        obstacle's surface) and of everything placed."""
        if float(surface_gap.min()) < TRACKING_CLEARANCE_M:
            return False
        return all(float(np.hypot(*(centre - c))) >= radius + r + 0.1 for c, r in placed)

    walls: list[tuple[FloatArray, float]] = []
    for _ in range(int(rng.integers(1, 3))):
        for _attempt in range(50):
            leg = int(rng.integers(0, n_legs))
            u = np.array([math.cos(headings[leg]), math.sin(headings[leg])])
            normal = np.array([-u[1], u[0]]) * rng.choice([-1.0, 1.0])
            length = rng.uniform(1.5, 4.0)
            along = rng.uniform(0.0, legs[leg])
            mid = path[leg] + along * u + rng.uniform(0.9, 2.2) * normal
            ends = np.stack([mid - 0.5 * length * u, mid + 0.5 * length * u])
            gap = _segment_distance(samples, ends[0], ends[1])
            if fits(mid, 0.5 * length, gap):
                walls.append((ends, float(rng.uniform(0.5, 1.5))))
                placed.append((mid, 0.5 * length))
                break

    boxes: list[tuple[FloatArray, FloatArray, float, float]] = []
    cylinders: list[tuple[FloatArray, float, float]] = []
    arc = np.concatenate([[0.0], np.cumsum(legs)])
    for _ in range(int(rng.integers(4, 10))):
        is_box = rng.random() < 0.5
        for _attempt in range(50):
            s = rng.uniform(0.0, arc[-1])
            leg = min(int(np.searchsorted(arc, s, side="right")) - 1, n_legs - 1)
            u = np.array([math.cos(headings[leg]), math.sin(headings[leg])])
            normal = np.array([-u[1], u[0]]) * rng.choice([-1.0, 1.0])
            point = path[leg] + (s - arc[leg]) * u
            refl = float(rng.uniform(0.3, 2.0))
            if is_box:
                size = rng.uniform(0.15, 0.6, 2)
                yaw = float(rng.uniform(0.0, math.pi))
                radius = 0.5 * float(np.hypot(*size))
                centre = point + (rng.uniform(0.75, 2.0) + radius) * normal
                gap = _box_distance(samples, centre, size, yaw)
                if fits(centre, radius, gap):
                    boxes.append((centre, size, yaw, refl))
                    placed.append((centre, radius))
                    break
            else:
                radius = float(rng.uniform(0.05, 0.3))
                centre = point + (rng.uniform(0.75, 2.0) + radius) * normal
                gap = np.hypot(*(samples - centre).T) - radius
                if fits(centre, radius, gap):
                    cylinders.append((centre, radius, refl))
                    placed.append((centre, radius))
                    break

    movers: list[Mover] = []
    for _ in range(n_movers):
        for _attempt in range(50):
            s = rng.uniform(0.1, 0.9) * arc[-1]
            leg = min(int(np.searchsorted(arc, s, side="right")) - 1, n_legs - 1)
            crossing = headings[leg] + rng.uniform(math.pi / 4, 3 * math.pi / 4) * rng.choice(
                [-1.0, 1.0]
            )
            u = np.array([math.cos(crossing), math.sin(crossing)])
            point = path[leg] + (s - arc[leg]) * np.array(
                [math.cos(headings[leg]), math.sin(headings[leg])]
            )
            length = rng.uniform(2.0, 5.0)
            share = rng.uniform(0.3, 0.7)  # where along its own path it crosses
            ends = np.stack([point - share * length * u, point + (1.0 - share) * length * u])
            radius = float(rng.uniform(0.15, 0.3))
            if _walk_clear(ends, radius + MOVER_CLEARANCE_M, walls, placed[len(walls) :]):
                mover = Mover(
                    radius_m=radius,
                    reflectivity=float(rng.uniform(0.3, 2.0)),
                    path=ends,
                    speed_m_s=float(rng.uniform(0.2, 0.8)),
                )
                if walks_apart(movers, mover, horizon_s=TRACKING_SCENE_S):
                    movers.append(mover)
                    break

    # The room: around the path, the obstacles and the movers' paths.
    extent = [path] + [w for w, _ in walls] + [m.path for m in movers]
    extent += [c[None, :] + r * np.array([[1.0, 1.0], [-1.0, -1.0]]) for c, r in placed]
    every = np.concatenate(extent)
    lo = np.minimum(every.min(axis=0) - 0.5, path.min(axis=0) - 1.5)
    hi = np.maximum(every.max(axis=0) + 0.5, path.max(axis=0) + 1.5)
    lo, hi = lo - rng.uniform(0.0, 0.5, 2), hi + rng.uniform(0.0, 0.5, 2)
    room = np.array([lo, [hi[0], lo[1]], hi, [lo[0], hi[1]], lo])
    world = World.build(
        walls=[(room, float(rng.uniform(0.5, 1.5))), *walls],
        boxes=boxes,
        cylinders=cylinders,
        vehicle_pose=(0.0, 0.0, float(headings[0])),
        name=f"tracking scene, {len(movers)} movers",
        movers=movers,
    )
    return world, path


def _walk_clear(
    ends: FloatArray,
    clearance_m: float,
    walls: list[tuple[FloatArray, float]],
    objects: list[tuple[FloatArray, float]],
) -> bool:
    """Whether a mover's straight walk ``ends`` (2, 2) keeps its centre ``clearance_m``
    from every wall (its segment) and every box or cylinder (its bounding circle)."""
    walk = _path_samples(ends, 0.02)
    for wall, _ in walls:
        if float(_segment_distance(walk, wall[0], wall[1]).min()) < clearance_m:
            return False
    return all(
        float(np.hypot(*(walk - centre).T).min()) >= radius + clearance_m
        for centre, radius in objects
    )


def _path_samples(path: FloatArray, spacing_m: float) -> FloatArray:
    """(q, 2) points along the polyline ``path`` at most ``spacing_m`` apart, ends included."""
    pieces = []
    for a, b in itertools.pairwise(path):
        n = max(1, math.ceil(float(np.hypot(*(b - a))) / spacing_m))
        pieces.append(a + np.linspace(0.0, 1.0, n + 1)[:-1, None] * (b - a))
    pieces.append(path[-1:])
    return np.concatenate(pieces)


def _segment_distance(points: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """(q,) distances from ``points`` (q, 2) to the segment ``a``-``b``, metres."""
    e = b - a
    t = np.clip((points - a) @ e / float(e @ e), 0.0, 1.0)
    nearest = a + t[:, None] * e
    return np.asarray(np.hypot(*(points - nearest).T), dtype=np.float64)


def _box_distance(
    points: FloatArray, centre: FloatArray, size: FloatArray, yaw: float
) -> FloatArray:
    """(q,) distances from ``points`` (q, 2) to a box's outline (0 inside it), metres."""
    c, s = math.cos(yaw), math.sin(yaw)
    local = (points - centre) @ np.array([[c, -s], [s, c]])
    outside = np.maximum(np.abs(local) - 0.5 * size, 0.0)
    return np.asarray(np.hypot(*outside.T), dtype=np.float64)
