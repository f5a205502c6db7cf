"""Compiled loops of :mod:`agent.tracking.visibility` (why compiled: :mod:`agent.compiled`).

Each loops over beams (a few hundred a scan) and, for visibility, over the tracks in reach
with an early exit; written in numpy the same tests are a dozen (tracks × beams) array
passes per call, most of the tracker's time budget on their own.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.compiled import compiled

BoolArray = NDArray[np.bool_]
FLAG_VALID, FLAG_NO_READING, FLAG_OUT_OF_RANGE = 0, 1, 3


@compiled
def scan_beams(
    points_xy: FloatArray,
    origin_xy: FloatArray,
    scan_angle_rad: FloatArray,
    range_m: FloatArray,
    flag: NDArray[np.uint8],
    min_range_m: float,
    max_range_m: float,
) -> tuple[FloatArray, FloatArray, BoolArray, BoolArray, int]:
    """Headings (n,), clear distance ``seen`` (n,, NaN unusable), ``hit`` (n,) and ``usable``
    (n,) per sample, and the count of valid samples (0: headings unknown).

    Heading of a valid sample: the direction from its origin to its point; of any other,
    its scan angle plus the offset (heading − scan angle) interpolated linearly over the
    index between the valid neighbours (held beyond the first and last), unwrapped as it
    goes. ``seen``: a valid sample's range; no reading or out of range beyond the far limit:
    ``max_range_m``; out of range nearer than the near limit: its range; other flags: NaN.
    """
    n = flag.shape[0]
    offset = np.empty(n)
    valid = np.zeros(n, dtype=np.bool_)
    count = 0
    last = -1
    last_off = 0.0
    for i in range(n):
        px, py = points_xy[i, 0], points_xy[i, 1]
        if flag[i] == FLAG_VALID and math.isfinite(px) and math.isfinite(py):
            off = math.atan2(py - origin_xy[i, 1], px - origin_xy[i, 0]) - scan_angle_rad[i]
            if count:
                d = off - last_off
                off = last_off + (d - 2.0 * math.pi * math.floor(d / (2.0 * math.pi) + 0.5))
            offset[i] = off
            valid[i] = True
            if count == 0:
                for j in range(i):
                    offset[j] = off
            else:
                for j in range(last + 1, i):
                    f = (j - last) / (i - last)
                    offset[j] = (1.0 - f) * last_off + f * off
            last, last_off = i, off
            count += 1
    for j in range(last + 1, n):
        offset[j] = last_off
    heading = np.empty(n)
    seen = np.empty(n)
    hit = np.zeros(n, dtype=np.bool_)
    usable = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        heading[i] = scan_angle_rad[i] + offset[i]
        r = range_m[i]
        if valid[i] or (flag[i] == FLAG_OUT_OF_RANGE and math.isfinite(r) and r < min_range_m):
            seen[i] = r
            hit[i] = True
        elif flag[i] == FLAG_NO_READING or flag[i] == FLAG_OUT_OF_RANGE:
            seen[i] = max_range_m
        else:
            seen[i] = np.nan
        usable[i] = not math.isnan(seen[i])
    return heading, seen, hit, usable, count


@compiled
def point_visibility(
    points: FloatArray,
    radius_m: FloatArray,
    footprint_m: FloatArray,
    sigma_m: FloatArray,
    min_beams: NDArray[np.int64],
    two_sided: BoolArray,
    origin_xy: FloatArray,
    cos_h: FloatArray,
    sin_h: FloatArray,
    seen_m: FloatArray,
    min_range_m: float,
    max_range_m: float,
    margin_m: float,
) -> tuple[BoolArray, BoolArray]:
    """``visible`` and ``occluded`` (k,) for points (k, 2): see
    :func:`agent.tracking.visibility.point_visibility`."""
    k = points.shape[0]
    n = cos_h.shape[0]
    visible = np.zeros(k, dtype=np.bool_)
    occluded = np.zeros(k, dtype=np.bool_)
    for t in range(k):
        foot = footprint_m[t]
        rad = radius_m[t]
        slack = 3.0 * sigma_m[t] + margin_m
        n_left = 0
        n_right = 0
        blocked = False
        for i in range(n):
            dx = points[t, 0] - origin_xy[i, 0]
            dy = points[t, 1] - origin_xy[i, 1]
            along = dx * cos_h[i] + dy * sin_h[i]
            if along <= 0.0:
                continue
            signed = dy * cos_h[i] - dx * sin_h[i]
            if abs(signed) > foot:
                continue
            surface = math.sqrt(dx * dx + dy * dy) - rad
            if surface < min_range_m or surface > max_range_m:
                continue
            if seen_m[i] >= surface - slack:
                if signed > 0.0:
                    n_left += 1
                else:
                    n_right += 1
            else:
                blocked = True
        need = min_beams[t]
        both = n_left >= need and n_right >= need
        vis = both if two_sided[t] else n_left + n_right >= need
        visible[t] = vis
        occluded[t] = (not vis) and blocked
    return visible, occluded


@compiled
def segment_visibility(
    alpha_rad: FloatArray,
    rho_m: FloatArray,
    lo_m: FloatArray,
    hi_m: FloatArray,
    sigma_m: FloatArray,
    min_beams: int,
    origin_xy: FloatArray,
    cos_h: FloatArray,
    sin_h: FloatArray,
    seen_m: FloatArray,
    min_range_m: float,
    max_range_m: float,
    margin_m: float,
    min_cos_incidence: float,
) -> tuple[BoolArray, BoolArray]:
    """``visible`` and ``occluded`` (k,) for segments: see
    :func:`agent.tracking.visibility.segment_visibility`."""
    k = alpha_rad.shape[0]
    n = cos_h.shape[0]
    visible = np.zeros(k, dtype=np.bool_)
    occluded = np.zeros(k, dtype=np.bool_)
    for t in range(k):
        c = math.cos(alpha_rad[t])
        s = math.sin(alpha_rad[t])
        slack = 3.0 * sigma_m[t] + margin_m
        count = 0
        blocked = False
        for i in range(n):
            denom = cos_h[i] * c + sin_h[i] * s
            if abs(denom) < min_cos_incidence:
                continue
            ox, oy = origin_xy[i, 0], origin_xy[i, 1]
            d = (rho_m[t] - ox * c - oy * s) / denom
            if d < min_range_m or d > max_range_m:
                continue
            px = ox + d * cos_h[i]
            py = oy + d * sin_h[i]
            u = -px * s + py * c
            if u < lo_m[t] or u > hi_m[t]:
                continue
            if seen_m[i] >= d - slack:
                count += 1
            else:
                blocked = True
        visible[t] = count >= min_beams
        occluded[t] = count < min_beams and blocked
    return visible, occluded


@compiled
def segment_ends_seen(
    ends: FloatArray,
    alpha: FloatArray,
    rho: FloatArray,
    points_xy: FloatArray,
    origin_xy: FloatArray,
    range_m: FloatArray,
    flag: NDArray[np.uint8],
    max_range_m: float,
    margin_m: float,
    skip: int,
) -> BoolArray:
    """See :func:`agent.tracking.visibility.segment_ends_seen` (``ends`` (k, 2, 2))."""
    k = ends.shape[0]
    n = flag.shape[0]
    out = np.zeros((k, 2), dtype=np.bool_)
    for f in range(k):
        c, s = math.cos(alpha[f]), math.sin(alpha[f])
        for e in range(2):
            ex, ey = ends[f, e, 0], ends[f, e, 1]
            best = -1
            best_d = np.inf
            for i in range(n):
                if flag[i] != 0 or not (math.isfinite(points_xy[i, 0]) and
                                        math.isfinite(points_xy[i, 1])):  # fmt: skip
                    continue
                d = (points_xy[i, 0] - ex) ** 2 + (points_xy[i, 1] - ey) ** 2
                if d < best_d:
                    best_d, best = d, i
            if best < 0:
                continue
            step = -1 if e == 0 else 1
            j = -1
            for o in range(1, skip + 2):
                cand = best + step * o
                if cand < 0 or cand >= n:
                    break
                fl = flag[cand]
                if fl == 0 or fl == 1 or fl == 3:
                    j = cand
                    break
            if j < 0:
                continue
            ox, oy = origin_xy[j, 0], origin_xy[j, 1]
            if flag[j] == 0 and math.isfinite(points_xy[j, 0]):
                bx, by = points_xy[j, 0] - ox, points_xy[j, 1] - oy
            else:  # no point: the end's own direction, a few beams off
                bx, by = ex - ox, ey - oy
            norm = math.hypot(bx, by)
            if norm <= 0.0:
                continue
            bx, by = bx / norm, by / norm
            den = bx * c + by * s
            t_line = (rho[f] - ox * c - oy * s) / den if den != 0.0 else np.inf
            crosses = math.isfinite(t_line) and t_line > 0.0
            if flag[j] == 0:
                out[f, e] = not (crosses and range_m[j] < t_line - margin_m)
            else:
                out[f, e] = crosses and t_line <= max_range_m - margin_m
    return out


def warm_up() -> None:
    """Load (on a new machine: compile) every kernel here, with the argument types the
    tracker passes."""
    z2 = np.zeros((3, 2))
    z1 = np.zeros(3)
    flag = np.zeros(3, dtype=np.uint8)
    heading, seen, _, _, _ = scan_beams(z2 + 1.0, z2, z1, z1 + 1.0, flag, 0.4, 2.5)
    b = np.zeros(1, dtype=np.bool_)
    point_visibility(
        np.ones((1, 2)), np.zeros(1), np.ones(1), np.zeros(1), np.ones(1, dtype=np.int64), b,
        z2, np.cos(heading), np.sin(heading), seen, 0.4, 2.5, 0.05,
    )  # fmt: skip
    segment_visibility(
        np.zeros(1), np.ones(1), -np.ones(1), np.ones(1), np.zeros(1), 1, z2,
        np.cos(heading), np.sin(heading), seen, 0.4, 2.5, 0.05, 0.26,
    )  # fmt: skip
    segment_ends_seen(
        np.ones((1, 2, 2)), np.zeros(1), np.ones(1), z2 + 1.0, z2, z1 + 1.0, flag, 2.5, 0.05, 3
    )
