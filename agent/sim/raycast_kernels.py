"""The ray caster's compiled loops (used by :mod:`agent.sim.raycast` and by the simulator's
beams, :mod:`agent.sim.simulator`; why compiled: :mod:`agent.compiled`).

Each ray takes one pass over its candidate segments and circles and keeps the nearest hit:
no (rays x primitives) temporaries, and a segment whose ends lie on one side of the ray costs
two cross products. The simulator's beams (:func:`cast_beams`) add the return path from the
spot to the detector, and first drop, per block of beams, the obstacles that no beam of the
block nor its return path can reach. They live here, beside the loop they inline, so that the
compiled cache of each follows the code it was built from.

Geometry, with the 2-D cross product ``u x v = u_x v_y - u_y v_x``: a ray ``p + t d``
(``|d| = 1``) crosses the segment ``a + u e`` (``e = b - a``, ``u`` in [0, 1]) where
``s_a = d x (a - p)`` and ``s_b = d x (b - p)`` differ in sign (or one is zero), at
``t = ((a - p) x e) / (d x e)``; it meets the circle ``(c, r)`` at
``t = -f.d -+ sqrt((f.d)^2 - |f|^2 + r^2)`` with ``f = p - c``. Radians and metres, world
frame; segments and circles are numbered as in :class:`~agent.sim.world.World`.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled, compiled_inline

IntArray = npt.NDArray[np.int64]

# A ray and a segment whose directions' sine is below this are taken as parallel (no hit).
PARALLEL_SINE = 1e-12
# Beams per block that share one list of candidate obstacles (:func:`cast_beams`): a sweep's
# coarse beams 2.5 degrees apart, so that a block sees few obstacles.
BEAMS_PER_BLOCK = 16
# Slack on the candidate test's angles (radians) and distances (metres), far above their
# rounding error.
_ANGLE_SLACK = 1e-9
_DISTANCE_SLACK = 1e-9

# Columns of the packed tables (:func:`pack_world`), one row per segment or circle: the
# geometry, a bounding circle (segments), reflectivity and obstacle id (a float: exact
# below 2**53).
SEG_AX, SEG_AY, SEG_BX, SEG_BY, SEG_EX, SEG_EY, SEG_LIMIT = range(7)
SEG_MX, SEG_MY, SEG_HALF, SEG_REFL, SEG_ID = range(7, 12)
CIRC_X, CIRC_Y, CIRC_R, CIRC_REFL, CIRC_ID = range(5)


@compiled
def pack_world(
    seg_start: FloatArray,
    seg_end: FloatArray,
    seg_reflectivity: FloatArray,
    seg_obstacle: IntArray,
    circ_center: FloatArray,
    circ_radius: FloatArray,
    circ_reflectivity: FloatArray,
    circ_obstacle: IntArray,
) -> tuple[FloatArray, FloatArray]:
    """A world's arrays (:class:`~agent.sim.world.World`) as the two tables the loops read.

    Returns
    -------
    segments, circles
        (m, 12): start ``a``, end ``b``, ``e = b - a``, the value ``|d x e|`` must exceed for
        a ray to cross the segment (``PARALLEL_SINE·|e|``), midpoint and half length,
        reflectivity, obstacle id; (k, 5): centre, radius, reflectivity, obstacle id.
        Metres.
    """
    m, k = seg_start.shape[0], circ_center.shape[0]
    segments = np.empty((m, 12))
    for j in range(m):
        ax, ay, bx, by = seg_start[j, 0], seg_start[j, 1], seg_end[j, 0], seg_end[j, 1]
        ex, ey = bx - ax, by - ay
        length = math.hypot(ex, ey)
        segments[j, SEG_AX], segments[j, SEG_AY] = ax, ay
        segments[j, SEG_BX], segments[j, SEG_BY] = bx, by
        segments[j, SEG_EX], segments[j, SEG_EY] = ex, ey
        segments[j, SEG_LIMIT] = PARALLEL_SINE * length
        segments[j, SEG_MX], segments[j, SEG_MY] = 0.5 * (ax + bx), 0.5 * (ay + by)
        segments[j, SEG_HALF] = 0.5 * length
        segments[j, SEG_REFL], segments[j, SEG_ID] = seg_reflectivity[j], seg_obstacle[j]
    circles = np.empty((k, 5))
    for j in range(k):
        circles[j, CIRC_X], circles[j, CIRC_Y] = circ_center[j, 0], circ_center[j, 1]
        circles[j, CIRC_R] = circ_radius[j]
        circles[j, CIRC_REFL], circles[j, CIRC_ID] = circ_reflectivity[j], circ_obstacle[j]
    return segments, circles


@compiled_inline
def _nearest_hit(
    px: float,
    py: float,
    dx: float,
    dy: float,
    t_min: float,
    t_max: float,
    segments: FloatArray,
    circles: FloatArray,
    seg_rows: IntArray,
    circ_rows: IntArray,
) -> tuple[float, int, int]:
    """The nearest hit of the ray ``p + t d`` with ``t_min < t <= t_max`` among the segments
    ``seg_rows`` and the circles ``circ_rows`` (each in increasing order).

    Returns ``(t, segment, circle)``: the distance (inf if nothing is hit) and the row of
    the segment or of the circle hit (-1 for the other, or both if nothing is hit). Ties go
    to the first segment, then to the first circle. A ray that starts inside a circle meets
    its far side.
    """
    best, seg, circ = math.inf, -1, -1
    for j in seg_rows:
        apx, apy = segments[j, SEG_AX] - px, segments[j, SEG_AY] - py
        s_a = dx * apy - dy * apx
        s_b = dx * (segments[j, SEG_BY] - py) - dy * (segments[j, SEG_BX] - px)
        if s_a * s_b > 0.0:
            continue  # both ends on one side of the ray's line
        ex, ey = segments[j, SEG_EX], segments[j, SEG_EY]
        denom = dx * ey - dy * ex
        if not abs(denom) > segments[j, SEG_LIMIT]:
            continue
        t = (apx * ey - apy * ex) / denom
        if t_min < t <= t_max and t < best:
            best, seg = t, j
    for j in circ_rows:
        fx, fy = px - circles[j, CIRC_X], py - circles[j, CIRC_Y]
        fd = fx * dx + fy * dy
        r = circles[j, CIRC_R]
        disc = fd * fd - (fx * fx + fy * fy - r * r)
        if not disc >= 0.0:
            continue
        root = math.sqrt(disc)
        t = -fd - root
        if not t_min < t <= t_max:
            t = root - fd  # the near side is out of range: the far side may not be
            if not t_min < t <= t_max:
                continue
        if t < best:
            best, seg, circ = t, -1, j
    return best, seg, circ


@compiled_inline
def _hit_normal(
    px: float,
    py: float,
    dx: float,
    dy: float,
    t: float,
    seg: int,
    circ: int,
    segments: FloatArray,
    circles: FloatArray,
) -> tuple[float, float]:
    """Unit normal at the hit ``(t, seg, circ)`` of ``p + t d``, turned back toward the ray."""
    if seg >= 0:
        ex, ey = segments[seg, SEG_EX], segments[seg, SEG_EY]
        length = math.hypot(ex, ey)
        nx, ny = ey / length, -ex / length
    else:
        r = circles[circ, CIRC_R]
        nx = (px + t * dx - circles[circ, CIRC_X]) / r
        ny = (py + t * dy - circles[circ, CIRC_Y]) / r
        length = math.hypot(nx, ny)
        nx, ny = nx / length, ny / length
    if nx * dx + ny * dy > 0.0:
        return -nx, -ny
    return nx, ny


@compiled_inline
def _surface(seg: int, circ: int, segments: FloatArray, circles: FloatArray) -> tuple[float, int]:
    """(reflectivity, obstacle id) of the segment or circle hit."""
    if seg >= 0:
        return segments[seg, SEG_REFL], int(segments[seg, SEG_ID])
    return circles[circ, CIRC_REFL], int(circles[circ, CIRC_ID])


@compiled
def cast(
    origins: FloatArray,
    directions: FloatArray,
    t_min: float,
    t_max: float,
    segments: FloatArray,
    circles: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, IntArray]:
    """The first surface each ray meets (see :func:`agent.sim.raycast.cast_rays`).

    Parameters
    ----------
    origins
        (n, 2) ray origins, or (1, 2) shared by every ray, metres.
    directions
        (n, 2) unit ray directions.
    t_min, t_max
        Hits at distances in ``(t_min, t_max]`` count, metres (``t_max`` may be inf).
    segments, circles
        The world's tables (:func:`pack_world`).

    Returns
    -------
    distance, normal, reflectivity, obstacle
        (n,) metres, inf where nothing is hit; (n, 2) unit normal turned back toward the ray,
        NaN where nothing is hit; (n,) reflectivity, NaN where nothing is hit; (n,) obstacle
        id, -1 where nothing is hit.
    """
    n = directions.shape[0]
    shared = origins.shape[0] == 1
    seg_rows, circ_rows = np.arange(segments.shape[0]), np.arange(circles.shape[0])
    distance = np.full(n, math.inf)
    normal = np.full((n, 2), math.nan)
    reflectivity = np.full(n, math.nan)
    obstacle = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        k = 0 if shared else i
        px, py = origins[k, 0], origins[k, 1]
        dx, dy = directions[i, 0], directions[i, 1]
        t, seg, circ = _nearest_hit(
            px, py, dx, dy, t_min, t_max, segments, circles, seg_rows, circ_rows
        )
        if seg < 0 and circ < 0:
            continue
        distance[i] = t
        normal[i, 0], normal[i, 1] = _hit_normal(px, py, dx, dy, t, seg, circ, segments, circles)
        reflectivity[i], obstacle[i] = _surface(seg, circ, segments, circles)
    return distance, normal, reflectivity, obstacle


@compiled_inline
def _path_clear(
    sx: float,
    sy: float,
    ex: float,
    ey: float,
    margin: float,
    segments: FloatArray,
    circles: FloatArray,
    seg_rows: IntArray,
    circ_rows: IntArray,
) -> bool:
    """Whether the path from ``s`` to ``e`` crosses none of the segments ``seg_rows`` and
    circles ``circ_rows`` farther than ``margin`` from either end (a path no longer than
    ``2·margin`` is clear)."""
    vx, vy = ex - sx, ey - sy
    length = math.hypot(vx, vy)
    if length <= 2.0 * margin:
        return True
    _, seg, circ = _nearest_hit(
        sx, sy, vx / length, vy / length, margin, length - margin,
        segments, circles, seg_rows, circ_rows,
    )  # fmt: skip
    return seg < 0 and circ < 0


@compiled
def clear_paths(
    start: FloatArray, end: FloatArray, margin: float, segments: FloatArray, circles: FloatArray
) -> BoolArray:
    """(n,) whether each path ``start[i] -> end[i]`` ((n, 2), metres) is clear (see
    :func:`agent.sim.raycast.segment_clear`; ``segments``, ``circles`` from
    :func:`pack_world`)."""
    n = start.shape[0]
    seg_rows, circ_rows = np.arange(segments.shape[0]), np.arange(circles.shape[0])
    clear = np.empty(n, dtype=np.bool_)
    for i in range(n):
        clear[i] = _path_clear(
            start[i, 0], start[i, 1], end[i, 0], end[i, 1], margin,
            segments, circles, seg_rows, circ_rows,
        )  # fmt: skip
    return clear


@compiled_inline
def _bearing(
    x: float, y: float, radius: float, cx: float, cy: float, spread: float, reach: float
) -> tuple[float, float]:
    """Where the circle ``(x, y, radius)`` lies for rays from within ``spread`` of ``c`` that
    end no farther than ``reach``: ``(bearing, half_width)``, radians.

    Such a ray meets the circle only if its heading lies within ``half_width`` of
    ``bearing``: it passes within ``radius + spread`` of the centre as seen from ``c``, so
    the centre's direction lies within ``asin((radius + spread) / dist)`` of the ray's.
    ``half_width`` is inf where the rays may start inside the circle, -1 where it is out of
    reach.
    """
    vx, vy = x - cx, y - cy
    dist = math.hypot(vx, vy)
    r = radius + spread
    if dist <= r:
        return 0.0, math.inf
    if dist - r > reach + _DISTANCE_SLACK:
        return 0.0, -1.0
    return math.atan2(vy, vx), math.asin(r / dist) + _ANGLE_SLACK


@compiled_inline
def _wrap(angle: float) -> float:
    """``angle`` plus a multiple of 2·pi, in [-pi, pi)."""
    return angle - 2.0 * math.pi * math.floor((angle + math.pi) / (2.0 * math.pi))


@compiled_inline
def _beam(
    px: float,
    py: float,
    head_heading: float,
    heading: float,
    theta: float,
    max_range_m: float,
    baseline_m: float,
    baseline_edge_growth: float,
    scan_half_angle_rad: float,
    margin_m: float,
    segments: FloatArray,
    circles: FloatArray,
    seg_rows: IntArray,
    circ_rows: IntArray,
) -> tuple[float, bool, float, float, int]:
    """One beam of :func:`cast_beams` against the segments ``seg_rows`` and circles
    ``circ_rows``: (range, visible, reflectivity, cos_view, obstacle)."""
    cos_h, sin_h = math.cos(heading), math.sin(heading)
    norm = math.hypot(cos_h, sin_h)
    dx, dy = cos_h / norm, sin_h / norm
    t, seg, circ = _nearest_hit(
        px, py, dx, dy, 0.0, max_range_m, segments, circles, seg_rows, circ_rows
    )
    if seg < 0 and circ < 0:
        return math.inf, False, math.nan, 0.0, -1
    reflectivity, obstacle = _surface(seg, circ, segments, circles)
    nx, ny = _hit_normal(px, py, dx, dy, t, seg, circ, segments, circles)
    ratio = theta / scan_half_angle_rad
    baseline = baseline_m * (1.0 + baseline_edge_growth * ratio * ratio)
    rx, ry = px - baseline * math.sin(head_heading), py + baseline * math.cos(head_heading)
    sx, sy = px + t * cos_h, py + t * sin_h
    visible = _path_clear(sx, sy, rx, ry, margin_m, segments, circles, seg_rows, circ_rows)
    vx, vy = rx - sx, ry - sy
    length = math.sqrt(vx * vx + vy * vy)
    cos_view = min(max(nx * (vx / length) + ny * (vy / length), 0.0), 1.0)
    return t, visible, reflectivity, cos_view, obstacle


@compiled
def _block_candidates(
    origin: FloatArray,
    heading: FloatArray,
    reach: float,
    reach_spread: float,
    segments: FloatArray,
    circles: FloatArray,
) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """The obstacles each block of ``BEAMS_PER_BLOCK`` beams may meet, on the beam or on its
    return path to a viewpoint within ``reach_spread`` of the beam's origin.

    A point of the return path from the spot ``o + t d`` to a viewpoint ``o + b`` lies at
    ``o + μb + (1 - μ)t d`` (``μ`` in [0, 1]): on a ray in direction ``d``, no longer than
    ``t``, from within ``|b|`` of ``o``. So both are rays of the block's directions, from
    within (origins' spread + ``reach_spread``) of the origins' centre, no longer than
    ``reach``.

    Returns
    -------
    seg_rows, seg_count, circ_rows, circ_count
        (blocks, m) and (blocks, k): the rows of each block's candidate segments and circles,
        in increasing order, the first ``seg_count[b]`` and ``circ_count[b]`` of each row.
    """
    n = heading.shape[0]
    blocks = (n + BEAMS_PER_BLOCK - 1) // BEAMS_PER_BLOCK
    x_lo, x_hi = origin[:, 0].min(), origin[:, 0].max()
    y_lo, y_hi = origin[:, 1].min(), origin[:, 1].max()
    cx, cy = 0.5 * (x_lo + x_hi), 0.5 * (y_lo + y_hi)
    spread = 0.5 * math.hypot(x_hi - x_lo, y_hi - y_lo) + reach_spread
    m, k = segments.shape[0], circles.shape[0]
    # Segments (by their bounding circles) first, then circles.
    bearing, half_width = np.empty(m + k), np.empty(m + k)
    for j in range(m):
        bearing[j], half_width[j] = _bearing(
            segments[j, SEG_MX], segments[j, SEG_MY], segments[j, SEG_HALF],
            cx, cy, spread, reach,
        )  # fmt: skip
    for j in range(k):
        bearing[m + j], half_width[m + j] = _bearing(
            circles[j, CIRC_X], circles[j, CIRC_Y], circles[j, CIRC_R], cx, cy, spread, reach
        )
    seg_rows = np.empty((blocks, m), dtype=np.int64)
    circ_rows = np.empty((blocks, k), dtype=np.int64)
    seg_count = np.zeros(blocks, dtype=np.int64)
    circ_count = np.zeros(blocks, dtype=np.int64)
    for b in range(blocks):
        h = heading[b * BEAMS_PER_BLOCK : min(n, (b + 1) * BEAMS_PER_BLOCK)]
        h_lo, h_hi = h.min(), h.max()
        mid, half = _wrap(0.5 * (h_lo + h_hi)), 0.5 * (h_hi - h_lo)
        for j in range(m + k):
            if half_width[j] < 0.0:
                continue
            off = bearing[j] - mid  # in (-2 pi, 2 pi)
            off = off - 2.0 * math.pi if off >= math.pi else off
            off = off + 2.0 * math.pi if off < -math.pi else off
            if abs(off) <= half + half_width[j]:
                if j < m:
                    seg_rows[b, seg_count[b]] = j
                    seg_count[b] += 1
                else:
                    circ_rows[b, circ_count[b]] = j - m
                    circ_count[b] += 1
    return seg_rows, seg_count, circ_rows, circ_count


@compiled
def cast_beams(
    origin: FloatArray,
    head_heading: FloatArray,
    heading: FloatArray,
    theta: FloatArray,
    max_range_m: float,
    baseline_m: float,
    baseline_edge_growth: float,
    scan_half_angle_rad: float,
    margin_m: float,
    segments: FloatArray,
    circles: FloatArray,
) -> tuple[FloatArray, BoolArray, FloatArray, FloatArray, IntArray]:
    """The simulator's beams: first hit, return path to the detector and viewing angle.

    Each beam leaves ``origin[i]`` along ``heading[i]`` and meets the first surface within
    ``max_range_m``. The detector's virtual viewpoint lies ``d(θ) = baseline_m·(1 +
    baseline_edge_growth·(θ/scan_half_angle_rad)²)`` to the left of the head's own heading
    (eq. 6.5); the spot is visible where the straight path from it to that viewpoint is
    clear (surfaces within ``margin_m`` of either end ignored), and is seen at the cosine of
    the angle between the surface normal and the direction to the viewpoint. Consecutive
    beams should point in similar directions from nearby origins (a sweep, or parts of one):
    each block of them is cast against the obstacles it may reach.

    Parameters
    ----------
    origin
        (n, 2) centre of scanning per beam, world frame, metres.
    head_heading
        (n,) the head's heading (vehicle yaw plus pan), radians.
    heading
        (n,) the beam's heading, radians.
    theta
        (n,) mirror angle θ, radians.
    max_range_m, baseline_m, baseline_edge_growth, scan_half_angle_rad, margin_m
        As above.
    segments, circles
        The world's tables (:func:`pack_world`).

    Returns
    -------
    range_m, visible, reflectivity, cos_view, obstacle
        (n,) distance to the hit, metres, inf where nothing is hit; (n,) bool, the return
        path is clear (False where nothing is hit); (n,) reflectivity, NaN where nothing is
        hit; (n,) viewing cosine clipped to [0, 1], 0 where nothing is hit; (n,) obstacle id,
        -1 where nothing is hit.
    """
    n = heading.shape[0]
    range_m = np.empty(n)
    visible = np.empty(n, dtype=np.bool_)
    reflectivity = np.empty(n)
    cos_view = np.empty(n)
    obstacle = np.empty(n, dtype=np.int64)
    if n == 0:
        return range_m, visible, reflectivity, cos_view, obstacle
    widest_baseline = baseline_m
    for i in range(n):
        ratio = theta[i] / scan_half_angle_rad
        widest_baseline = max(
            widest_baseline, baseline_m * (1.0 + baseline_edge_growth * ratio * ratio)
        )
    seg_rows, seg_count, circ_rows, circ_count = _block_candidates(
        origin, heading, max_range_m, widest_baseline, segments, circles
    )
    for i in range(n):
        b = i // BEAMS_PER_BLOCK
        range_m[i], visible[i], reflectivity[i], cos_view[i], obstacle[i] = _beam(
            origin[i, 0], origin[i, 1], head_heading[i], heading[i], theta[i], max_range_m,
            baseline_m, baseline_edge_growth, scan_half_angle_rad, margin_m,
            segments, circles, seg_rows[b, : seg_count[b]], circ_rows[b, : circ_count[b]],
        )  # fmt: skip
    return range_m, visible, reflectivity, cos_view, obstacle


# Columns of the movers' table (:func:`cast_beams_moving`), one row per mover.
MOVER_R, MOVER_REFL, MOVER_ID = range(3)


@compiled_inline
def _circle_hit(
    px: float, py: float, dx: float, dy: float, t_min: float, t_max: float,
    cx: float, cy: float, r: float,
) -> float:  # fmt: skip
    """Distance along ``p + t d`` to the circle ``(c, r)`` within ``(t_min, t_max]`` (the near
    side, else the far side), inf if none: the circle test of :func:`_nearest_hit`."""
    fx, fy = px - cx, py - cy
    fd = fx * dx + fy * dy
    disc = fd * fd - (fx * fx + fy * fy - r * r)
    if not disc >= 0.0:
        return math.inf
    root = math.sqrt(disc)
    t = -fd - root
    if not t_min < t <= t_max:
        t = root - fd
        if not t_min < t <= t_max:
            return math.inf
    return t


@compiled_inline
def _movers_clear(
    sx: float, sy: float, ex: float, ey: float, margin: float,
    mover_xy: FloatArray, i: int, movers: FloatArray,
) -> bool:  # fmt: skip
    """Whether the path from ``s`` to ``e`` misses every mover where it is at beam ``i``
    (surfaces within ``margin`` of either end ignored, as in :func:`_path_clear`)."""
    vx, vy = ex - sx, ey - sy
    length = math.hypot(vx, vy)
    if length <= 2.0 * margin:
        return True
    dx, dy = vx / length, vy / length
    for j in range(movers.shape[0]):
        t = _circle_hit(
            sx, sy, dx, dy, margin, length - margin,
            mover_xy[i, j, 0], mover_xy[i, j, 1], movers[j, MOVER_R],
        )  # fmt: skip
        if t < math.inf:
            return False
    return True


@compiled
def cast_beams_moving(
    origin: FloatArray,
    head_heading: FloatArray,
    heading: FloatArray,
    theta: FloatArray,
    max_range_m: float,
    baseline_m: float,
    baseline_edge_growth: float,
    scan_half_angle_rad: float,
    margin_m: float,
    segments: FloatArray,
    circles: FloatArray,
    mover_xy: FloatArray,
    movers: FloatArray,
) -> tuple[FloatArray, BoolArray, FloatArray, FloatArray, IntArray]:
    """:func:`cast_beams` in a world with movers, each where it is at its beam's time.

    Each beam is first cast against the static world exactly as :func:`cast_beams` does;
    then against every mover's circle at ``mover_xy[i, j]``: the nearer hit wins (a tie goes
    to the static surface), and the return path to the detector must miss the static world
    and every mover. Movers are not culled per block (they are few, and a circle test is a
    dozen operations).

    Parameters
    ----------
    origin, head_heading, heading, theta, max_range_m, baseline_m, baseline_edge_growth,
    scan_half_angle_rad, margin_m, segments, circles
        As for :func:`cast_beams`.
    mover_xy
        (n, m, 2): each mover's centre at each beam's time, world frame, metres.
    movers
        (m, 3): radius (m), reflectivity, obstacle id (a float, exact below 2**53).

    Returns
    -------
    range_m, visible, reflectivity, cos_view, obstacle
        As for :func:`cast_beams`; a beam that meets a mover names the mover's id.
    """
    n = heading.shape[0]
    range_m = np.empty(n)
    visible = np.empty(n, dtype=np.bool_)
    reflectivity = np.empty(n)
    cos_view = np.empty(n)
    obstacle = np.empty(n, dtype=np.int64)
    if n == 0:
        return range_m, visible, reflectivity, cos_view, obstacle
    widest_baseline = baseline_m
    for i in range(n):
        ratio = theta[i] / scan_half_angle_rad
        widest_baseline = max(
            widest_baseline, baseline_m * (1.0 + baseline_edge_growth * ratio * ratio)
        )
    seg_rows, seg_count, circ_rows, circ_count = _block_candidates(
        origin, heading, max_range_m, widest_baseline, segments, circles
    )
    for i in range(n):
        b = i // BEAMS_PER_BLOCK
        s_rows, c_rows = seg_rows[b, : seg_count[b]], circ_rows[b, : circ_count[b]]
        px, py = origin[i, 0], origin[i, 1]
        cos_h, sin_h = math.cos(heading[i]), math.sin(heading[i])
        norm = math.hypot(cos_h, sin_h)
        dx, dy = cos_h / norm, sin_h / norm
        t, seg, circ = _nearest_hit(
            px, py, dx, dy, 0.0, max_range_m, segments, circles, s_rows, c_rows
        )
        mover = -1
        for j in range(movers.shape[0]):
            tj = _circle_hit(
                px, py, dx, dy, 0.0, max_range_m,
                mover_xy[i, j, 0], mover_xy[i, j, 1], movers[j, MOVER_R],
            )  # fmt: skip
            if tj < t:
                t, mover = tj, j
        if mover < 0 and seg < 0 and circ < 0:
            range_m[i], visible[i], reflectivity[i] = math.inf, False, math.nan
            cos_view[i], obstacle[i] = 0.0, -1
            continue
        if mover >= 0:
            r = movers[mover, MOVER_R]
            nx = (px + t * dx - mover_xy[i, mover, 0]) / r
            ny = (py + t * dy - mover_xy[i, mover, 1]) / r
            length = math.hypot(nx, ny)
            nx, ny = nx / length, ny / length
            if nx * dx + ny * dy > 0.0:
                nx, ny = -nx, -ny
            refl, obs = movers[mover, MOVER_REFL], int(movers[mover, MOVER_ID])
        else:
            nx, ny = _hit_normal(px, py, dx, dy, t, seg, circ, segments, circles)
            refl, obs = _surface(seg, circ, segments, circles)
        ratio = theta[i] / scan_half_angle_rad
        baseline = baseline_m * (1.0 + baseline_edge_growth * ratio * ratio)
        hh = head_heading[i]
        rx, ry = px - baseline * math.sin(hh), py + baseline * math.cos(hh)
        sx, sy = px + t * cos_h, py + t * sin_h
        seen = _path_clear(sx, sy, rx, ry, margin_m, segments, circles, s_rows, c_rows)
        if seen:
            seen = _movers_clear(sx, sy, rx, ry, margin_m, mover_xy, i, movers)
        vx, vy = rx - sx, ry - sy
        length = math.sqrt(vx * vx + vy * vy)
        range_m[i], visible[i], reflectivity[i], obstacle[i] = t, seen, refl, obs
        cos_view[i] = min(max(nx * (vx / length) + ny * (vy / length), 0.0), 1.0)
    return range_m, visible, reflectivity, cos_view, obstacle
