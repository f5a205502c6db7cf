"""The compiled loops of the free-space map (:mod:`agent.planning.free_space`).

Written in numpy, a scan's update of the map cost about 1-1.6 ms and a profile 0.3-0.6 ms
(p50 on the planner stage's scans; p99 up to 2 ms each), most of it in passes over whole
arrays (every sample of every span, every cell of the scanned wedge's box twice or three
times, a Euclidean distance transform, the grid compared with the query time) and in the
call overhead of a few dozen small-array operations (see :mod:`agent.compiled`). Here each
runs as one loop over the cells or samples it concerns, an update in one call
(:func:`add_scan`), a profile in another (:func:`profile_ranges`):

* :func:`footprint_cells` samples the spans, stopping at each span's end;
* :func:`hit_cells` dilates the hits' cells;
* :func:`deepen` draws the scanned wedge and the hiding places in the box and gives each
  footprint cell its distance to the nearest hiding place, exact as far as a deadline depends
  on it (:func:`squared_distances`: a distance along columns, then a search along the row no
  wider than that distance; beyond the reach of a deadline, any larger distance gives the
  same one), and extends the footprint's deadlines;
* :func:`march_rays` walks each profile ray from where it leaves the vehicle's body to its
  first cell not free at the query time, looking at nothing beyond it.

Each computes what :mod:`agent.planning.free_space` documents, with the same floating-point
operations in the same order as the numpy formulation it replaced (numba, like numpy, fuses
no multiply with an add; the transcendental functions and the matrix products are left to
numpy, in the caller), so that the cells, the distances and the deadlines are the same to the
bit; the tests compare them with that formulation on synthetic scans and on the simulator
chain's.

Cell indices are ``(i, j)`` of ``free_until[i, j]``: ``i`` along ``odom`` x, ``j`` along y,
``i = floor((x − origin_x) / cell_m)``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.compiled import compiled, compiled_inline

IntArray = NDArray[np.int64]


@compiled_inline
def _cell(coordinate_m: float, corner_m: float, cell_m: float, size: int) -> int:
    """``floor((coordinate − corner) / cell_m)``, the index of a cell along one axis, held to
    ``[−1, size]`` (−1 for NaN): off the grid stays off it, and no conversion overflows."""
    index = np.floor((coordinate_m - corner_m) / cell_m)
    if not index >= -1.0:
        return -1
    if index > size:
        return size
    return int(index)


@compiled
def footprint_cells(
    beam_xy: FloatArray,
    x: float,
    y: float,
    cos_h: FloatArray,
    sin_h: FloatArray,
    start_m: FloatArray,
    end_m: FloatArray,
    step_m: float,
    n_along: int,
    grid_x: float,
    grid_y: float,
    cell_m: float,
    size: int,
) -> tuple[IntArray, IntArray]:
    """Cells of the span samples ``along = min(start + m·step, end)``, m = 0 ... ``n_along``
    − 1, up to the first sample clamped at the end (the later ones repeat it), at
    ``(beam_xy + (x, y)) + along · (cos h, sin h)`` (``odom``, m; ``beam_xy`` (n, 2) the
    beams' origins turned into ``odom`` axes); only the cells on the grid (``size`` a side,
    its cell (0, 0)'s corner at ``(grid_x, grid_y)``). Spans with ``end <= start`` give
    none."""
    n = cos_h.size
    total = 0
    for b in range(n):
        if end_m[b] > start_m[b]:
            total += min(n_along, math.ceil((end_m[b] - start_m[b]) / step_m) + 2)
    fi = np.empty(total, dtype=np.int64)
    fj = np.empty(total, dtype=np.int64)
    k = 0
    for b in range(n):
        start, end = start_m[b], end_m[b]
        if not end > start:
            continue
        ox, oy = beam_xy[b, 0] + x, beam_xy[b, 1] + y
        for m in range(n_along):
            along = start + m * step_m
            last = along >= end
            if last:
                along = end
            i = _cell(ox + along * cos_h[b], grid_x, cell_m, size)
            j = _cell(oy + along * sin_h[b], grid_y, cell_m, size)
            if 0 <= i < size and 0 <= j < size and k < total:
                fi[k] = i
                fj[k] = j
                k += 1
            if last:
                break
    return fi[:k], fj[:k]


@compiled
def hit_cells(
    hits_xy: FloatArray,
    x: float,
    y: float,
    offsets: IntArray,
    grid_x: float,
    grid_y: float,
    cell_m: float,
    size: int,
) -> tuple[IntArray, IntArray]:
    """Cells within the dilation ``offsets`` ((m, 2) cells) of the hits' cells, for the hits
    at ``hits_xy + (x, y)`` (``odom``, m; ``hits_xy`` (n, 2) turned into ``odom`` axes) whose
    own cell is on the grid; only cells on the grid."""
    n, m = hits_xy.shape[0], offsets.shape[0]
    hi = np.empty(n * m, dtype=np.int64)
    hj = np.empty(n * m, dtype=np.int64)
    k = 0
    for a in range(n):
        i = _cell(hits_xy[a, 0] + x, grid_x, cell_m, size)
        j = _cell(hits_xy[a, 1] + y, grid_y, cell_m, size)
        if not (0 <= i < size and 0 <= j < size):
            continue
        for o in range(m):
            ii, jj = i + offsets[o, 0], j + offsets[o, 1]
            if 0 <= ii < size and 0 <= jj < size:
                hi[k] = ii
                hj[k] = jj
                k += 1
    return hi[:k], hj[:k]


@compiled
def _column_distances(hiding: NDArray[np.bool_], reach: int) -> IntArray:
    """Per cell, the distance (cells) along its column (axis 0) to the nearest ``True`` cell,
    held to at most ``reach + 1``."""
    ni, nj = hiding.shape
    g = np.empty((ni, nj), dtype=np.int64)
    for j in range(nj):
        g[0, j] = 0 if hiding[0, j] else reach + 1
    for i in range(1, ni):
        for j in range(nj):
            g[i, j] = 0 if hiding[i, j] else min(g[i - 1, j] + 1, reach + 1)
    for i in range(ni - 2, -1, -1):
        for j in range(nj):
            g[i, j] = min(g[i, j], g[i + 1, j] + 1)
    return g


@compiled_inline
def _nearest_squared(g: IntArray, a: int, b: int, reach: int) -> int:
    """The squared distance (cells²) from cell (a, b) to the nearest ``True`` cell, given the
    column distances ``g`` (:func:`_column_distances`): exact when it is ``reach²`` or less,
    more than ``reach²`` otherwise. The nearest cell's column q satisfies |b − q| <= g[a, b]
    (column b itself gives g[a, b]²) and |b − q| <= reach when the distance is within reach,
    so only those columns are searched (a held column distance can only come out smaller
    than the truth where it exceeds reach, and then its term still exceeds reach²)."""
    nj = g.shape[1]
    best = int(g[a, b] * g[a, b])
    w = min(int(g[a, b]), reach)
    for q in range(max(0, b - w), min(nj, b + w + 1)):
        d = int((b - q) * (b - q) + g[a, q] * g[a, q])
        if d < best:
            best = d
    return best


@compiled
def squared_distances(hiding: NDArray[np.bool_], reach: int) -> IntArray:
    """For every cell, :func:`_nearest_squared`: the squared Euclidean distance (cells²) to
    the nearest ``True`` cell where it is within ``reach`` cells, more than ``reach²``
    elsewhere (also where there is no ``True`` cell)."""
    g = _column_distances(hiding, reach)
    out = np.empty(hiding.shape, dtype=np.int64)
    for a in range(hiding.shape[0]):
        for b in range(hiding.shape[1]):
            out[a, b] = _nearest_squared(g, a, b, reach)
    return out


@compiled
def _body_cells(
    body_xy: FloatArray, x: float, y: float, grid_x: float, grid_y: float, cell_m: float, size: int
) -> tuple[IntArray, IntArray]:
    """Cells on the grid of the points ``body_xy + (x, y)`` (``odom``, m)."""
    n = body_xy.shape[0]
    bi = np.empty(n, dtype=np.int64)
    bj = np.empty(n, dtype=np.int64)
    k = 0
    for a in range(n):
        i = _cell(body_xy[a, 0] + x, grid_x, cell_m, size)
        j = _cell(body_xy[a, 1] + y, grid_y, cell_m, size)
        if 0 <= i < size and 0 <= j < size:
            bi[k] = i
            bj[k] = j
            k += 1
    return bi[:k], bj[:k]


@compiled
def deepen(
    free_until: FloatArray,
    grid_x: float,
    grid_y: float,
    cell_m: float,
    fi: IntArray,
    fj: IntArray,
    bi: IntArray,
    bj: IntArray,
    hi: IntArray,
    hj: IntArray,
    centre_x: float,
    centre_y: float,
    rim_x: FloatArray,
    rim_y: FloatArray,
    pad: int,
    lo_cs: tuple[float, float],
    hi_cs: tuple[float, float],
    mid_cs: tuple[float, float],
    far_m: float,
    edge_m: float,
    speed_m_s: float,
    max_age_s: float,
    scan_start_s: float,
) -> None:
    """Extend the deadlines of the footprint's cells (``fi, fj``, at least one), as
    :class:`agent.planning.free_space.FreeSpaceMap` documents.

    The box: the cells of the footprint, of the centre of scanning ``(centre_x, centre_y)``
    and of the wedge's rim points ``(rim_x, rim_y)`` (``odom``, m), padded by ``pad`` cells,
    cut to the grid. Per box cell, its centre ``(cx, cy)`` from the centre of scanning
    (``grid + (index + 0.5)·cell_m − centre``) lies wholly in the scanned wedge when
    ``cos(a_lo)·cy − sin(a_lo)·cx >= cell_m/√2`` (left of the low edge ray, ``lo_cs`` =
    (cos, sin) of its angle), ``sin(a_hi)·cx − cos(a_hi)·cy >= cell_m/√2`` (right of the high
    one), ``cos(mid)·cx + sin(mid)·cy > 0`` and ``cx² + cy² <= far_m²`` (signed distances
    from the edge rays by cross products: the wedge spans less than 180°). A cell the edge
    beams cut is partly outside the wedge, unobserved, and no hiding place of the wedge's own
    (the "flanks" of the module :mod:`agent.planning.free_space`). A hiding place: in the
    wedge and not in the footprint, unless in the body (``bi, bj``); or a hit (``hi, hj``).
    Each footprint cell not hiding gets ``depth = sqrt(d²)·cell_m`` (``d`` its distance in
    cells to the nearest hiding place of the box; infinite when there is none),
    ``keep = min((depth − edge_m) / speed_m_s, max_age_s)`` and, if ``keep > 0``,
    ``free_until = max(free_until, scan_start_s + keep)``. ``pad`` must exceed
    ``(edge_m + speed_m_s · max_age_s) / cell_m`` by a cell: a distance beyond ``pad`` is
    taken as infinite, whose ``keep`` (``max_age_s``) is every such distance's.
    """
    size = free_until.shape[0]
    lo_i = hi_i = _cell(centre_x, grid_x, cell_m, size)
    lo_j = hi_j = _cell(centre_y, grid_y, cell_m, size)
    for k in range(rim_x.size):
        i = _cell(rim_x[k], grid_x, cell_m, size)
        j = _cell(rim_y[k], grid_y, cell_m, size)
        lo_i, hi_i, lo_j, hi_j = min(lo_i, i), max(hi_i, i), min(lo_j, j), max(hi_j, j)
    for k in range(fi.size):
        lo_i, hi_i = min(lo_i, fi[k]), max(hi_i, fi[k])
        lo_j, hi_j = min(lo_j, fj[k]), max(hi_j, fj[k])
    i0, j0 = max(0, lo_i - pad), max(0, lo_j - pad)
    ni, nj = min(size, hi_i + pad + 1) - i0, min(size, hi_j + pad + 1) - j0
    # The one-axis terms of the wedge's tests, in the order of operations documented above.
    cx = np.empty(ni)
    cy = np.empty(nj)
    lo_x, hi_x, ahead_x, cx2 = np.empty(ni), np.empty(ni), np.empty(ni), np.empty(ni)
    lo_y, hi_y, ahead_y, cy2 = np.empty(nj), np.empty(nj), np.empty(nj), np.empty(nj)
    for a in range(ni):
        cx[a] = grid_x + (float(i0 + a) + 0.5) * cell_m - centre_x
        lo_x[a], hi_x[a], ahead_x[a] = lo_cs[1] * cx[a], hi_cs[1] * cx[a], mid_cs[0] * cx[a]
        cx2[a] = cx[a] * cx[a]
    for b in range(nj):
        cy[b] = grid_y + (float(j0 + b) + 0.5) * cell_m - centre_y
        lo_y[b], hi_y[b], ahead_y[b] = lo_cs[0] * cy[b], hi_cs[0] * cy[b], mid_cs[1] * cy[b]
        cy2[b] = cy[b] * cy[b]
    half_diag = cell_m / math.sqrt(2.0)
    far2 = far_m * far_m
    foot = np.zeros((ni, nj), dtype=np.bool_)
    for k in range(fi.size):
        foot[fi[k] - i0, fj[k] - j0] = True
    hiding = np.zeros((ni, nj), dtype=np.bool_)
    for a in range(ni):
        for b in range(nj):
            hiding[a, b] = (
                not foot[a, b]
                and lo_y[b] - lo_x[a] >= half_diag
                and hi_x[a] - hi_y[b] >= half_diag
                and ahead_x[a] + ahead_y[b] > 0
                and cx2[a] + cy2[b] <= far2
            )
    for k in range(bi.size):
        a, b = bi[k] - i0, bj[k] - j0
        if 0 <= a < ni and 0 <= b < nj:
            hiding[a, b] = False
    for k in range(hi.size):
        a, b = hi[k] - i0, hj[k] - j0
        if 0 <= a < ni and 0 <= b < nj:
            hiding[a, b] = True
    # Only the distances within ``pad`` cells matter: farther, every deadline is max_age_s
    # (the caller's pad exceeds (edge_m + speed_m_s · max_age_s) / cell_m by a cell).
    g = _column_distances(hiding, pad)
    for a in range(ni):
        for b in range(nj):
            if not foot[a, b] or hiding[a, b]:
                continue
            d2 = _nearest_squared(g, a, b, pad)
            depth = math.sqrt(float(d2)) * cell_m if d2 <= pad * pad else math.inf
            keep = min((depth - edge_m) / speed_m_s, max_age_s)
            if keep > 0:
                until = scan_start_s + keep
                if until > free_until[i0 + a, j0 + b]:
                    free_until[i0 + a, j0 + b] = until


@compiled
def add_scan(
    free_until: FloatArray,
    grid_x: float,
    grid_y: float,
    cell_m: float,
    x: float,
    y: float,
    beam_xy: FloatArray,
    cos_h: FloatArray,
    sin_h: FloatArray,
    start_m: FloatArray,
    end_m: FloatArray,
    step_m: float,
    hits_xy: FloatArray,
    hit_offsets: IntArray,
    wedge: bool,
    body_xy: FloatArray,
    centre_x: float,
    centre_y: float,
    rim_x: FloatArray,
    rim_y: FloatArray,
    pad: int,
    lo_cs: tuple[float, float],
    hi_cs: tuple[float, float],
    mid_cs: tuple[float, float],
    far_m: float,
    edge_m: float,
    speed_m_s: float,
    max_age_s: float,
    scan_start_s: float,
) -> None:
    """One scan into the map (:meth:`FreeSpaceMap.add`): the footprint
    (:func:`footprint_cells`, sampled every ``step_m`` up to ``ceil(longest span / step_m)``
    steps along every span), the hits' cells (:func:`hit_cells`), the deadlines
    (:func:`deepen`, when ``wedge`` and the footprint is not empty; ``body_xy`` the vehicle's
    lattice points turned into ``odom`` axes, placed at ``+ (x, y)``), then the hits' cells
    made not free. The grid is ``free_until``, its cell (0, 0)'s corner at
    ``(grid_x, grid_y)``."""
    size = free_until.shape[0]
    longest = -math.inf
    for b in range(start_m.size):
        if end_m[b] > start_m[b]:
            longest = max(longest, end_m[b] - start_m[b])
    n_along = math.ceil(longest / step_m) + 1 if longest > -math.inf else 0
    fi, fj = footprint_cells(
        beam_xy, x, y, cos_h, sin_h, start_m, end_m, step_m, n_along, grid_x, grid_y,
        cell_m, size,
    )  # fmt: skip
    hi, hj = hit_cells(hits_xy, x, y, hit_offsets, grid_x, grid_y, cell_m, size)
    if wedge and fi.size:
        bi, bj = _body_cells(body_xy, x, y, grid_x, grid_y, cell_m, size)
        deepen(
            free_until, grid_x, grid_y, cell_m, fi, fj, bi, bj, hi, hj, centre_x, centre_y,
            rim_x, rim_y, pad, lo_cs, hi_cs, mid_cs, far_m, edge_m, speed_m_s, max_age_s,
            scan_start_s,
        )  # fmt: skip
    for k in range(hi.size):
        free_until[hi[k], hj[k]] = -math.inf


@compiled
def march_rays(
    free_until: FloatArray,
    now_s: float,
    rel_x: float,
    rel_y: float,
    dir_x: FloatArray,
    dir_y: FloatArray,
    steps_m: FloatArray,
    exit_step: IntArray,
    cell_m: float,
    size: int,
) -> IntArray:
    """For each ray (direction ``(dir_x, dir_y)`` in ``odom``, from the centre of scanning at
    ``(rel_x, rel_y)`` relative to the grid's corner), the first step ``k >= exit_step`` whose
    sample ``floor((rel + steps_m[k]·dir) / cell_m)`` is off the grid or not free at
    ``now_s`` (``free_until < now_s``); ``steps_m.size`` if none is."""
    n_steps = steps_m.size
    out = np.empty(dir_x.size, dtype=np.int64)
    for r in range(dir_x.size):
        k = exit_step[r]
        while k < n_steps:
            d = steps_m[k]
            px = np.floor((rel_x + d * dir_x[r]) / cell_m)
            py = np.floor((rel_y + d * dir_y[r]) / cell_m)
            if not (px >= 0 and px < size and py >= 0 and py < size):
                break
            if not free_until[int(px), int(py)] >= now_s:
                break
            k += 1
        out[r] = k
    return out


@compiled
def profile_ranges(
    free_until: FloatArray,
    now_s: float,
    rel_x: float,
    rel_y: float,
    dir_x: FloatArray,
    dir_y: FloatArray,
    steps_m: FloatArray,
    exit_step: IntArray,
    cell_m: float,
) -> FloatArray:
    """The profile (:meth:`FreeSpaceMap.profile`) from its 2b sub-rays (:func:`march_rays`,
    the arguments as its): each sub-ray is known clear to the step before its first blocked
    one, or 0 when that is no further than its exit from the body; bearing k (sub-ray 2k)
    gets the least of sub-rays 2k − 1, 2k and 2k + 1 (indices modulo 2b)."""
    first = march_rays(
        free_until, now_s, rel_x, rel_y, dir_x, dir_y, steps_m, exit_step, cell_m,
        free_until.shape[0],
    )  # fmt: skip
    n = first.size // 2
    sub = np.empty(2 * n)
    for r in range(2 * n):
        sub[r] = steps_m[first[r] - 1] if first[r] > exit_step[r] else 0.0
    out = np.empty(n)
    for k in range(n):
        out[k] = min(sub[2 * k], min(sub[2 * k + 1], sub[2 * k - 1 if k else 2 * n - 1]))
    return out


@compiled
def end_hits(
    hit_at: FloatArray,
    now_s: float,
    rel_x: float,
    rel_y: float,
    dir_x: FloatArray,
    dir_y: FloatArray,
    ranges: FloatArray,
    beyond_m: FloatArray,
    base_reach_m: float,
    mover_speed_m_s: float,
    max_age_s: float,
    cell_m: float,
) -> NDArray[np.uint8]:
    """Which sectors of a profile end at a hit (:meth:`FreeSpaceMap.end_hits`): from the
    centre of scanning at ``(rel_x, rel_y)`` (m from the grid's corner), along sub-rays
    2k − 1, 2k and 2k + 1 (``dir_x``, ``dir_y`` (2b,), modulo 2b) of each lit bearing k
    (``ranges`` (b,) > 0), the steps ``beyond_m`` past ``ranges[k]``: 1 at the first cell
    whose hit (``hit_at``, its scan's start) is no older than ``max_age_s`` and lies within
    ``base_reach_m`` plus ``mover_speed_m_s`` times its age of the end."""
    n = ranges.size
    size_x, size_y = hit_at.shape
    out = np.zeros(n, dtype=np.uint8)
    oldest = now_s - max_age_s
    for k in range(n):
        end = ranges[k]
        if end <= 0.0:
            continue
        found = False
        for j in range(3):
            r = (2 * k - 1 + j) % (2 * n)
            for d in beyond_m:
                at = end + d
                ix = math.floor((rel_x + at * dir_x[r]) / cell_m)
                iy = math.floor((rel_y + at * dir_y[r]) / cell_m)
                if ix < 0 or iy < 0 or ix >= size_x or iy >= size_y:
                    break
                t = hit_at[ix, iy]
                if t >= oldest and d <= base_reach_m + mover_speed_m_s * max(now_s - t, 0.0):
                    found = True
                    break
            if found:
                break
        out[k] = found
    return out


@compiled
def beam_offsets(
    points_xy: FloatArray, origin_xy: FloatArray, range_m: FloatArray
) -> tuple[NDArray[np.bool_], FloatArray]:
    """Which samples have a point (its position and range finite), and each beam's offset
    ``points_xy − origin_xy`` (n, 2) m, zero where there is no point (:func:`scan_spans`'s
    first step; the headings are numpy's ``arctan2`` of it, in the caller)."""
    n = range_m.size
    has_point = np.zeros(n, dtype=np.bool_)
    d = np.zeros((n, 2))
    for k in range(n):
        px, py = points_xy[k, 0], points_xy[k, 1]
        if math.isfinite(px) and math.isfinite(py) and math.isfinite(range_m[k]):
            has_point[k] = True
            d[k, 0] = px - origin_xy[k, 0]
            d[k, 1] = py - origin_xy[k, 1]
    return has_point, d


@compiled_inline
def _wrap_angle(angle: float) -> float:
    """``(angle + π) mod 2π − π``, with Python's (and numpy's) floored modulo."""
    return (angle + np.pi) % (2 * np.pi) - np.pi


@compiled
def scan_evidence(
    heading: FloatArray,
    has_point: NDArray[np.bool_],
    range_m: FloatArray,
    sigma_m: FloatArray,
    flag: NDArray[np.uint8],
    intensity_a: FloatArray,
    told_known: bool,
    told_rad: FloatArray,
    constants: tuple[float, float, float, float, float, float, float, float, float, float],
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]:
    """The spans and hits of :func:`agent.planning.free_space.scan_spans` but for the vouched
    beams' ends (their ``vouch_range_m`` takes a cosine, left to numpy in the caller):
    ``(start_m, end_m, hit, vouched, known)``; ``heading`` is changed in place to the
    headings the spans use (the told headings ``told_rad`` (n,) for the no-returns, when
    ``told_known`` and they agree). ``constants``: near, far, range_sigmas, range_margin_m,
    signal_floor_A, noise_floor_A, the pan tolerance (rad), baseline_m / near, the shadow
    margin (rad), baseline_m. The told headings' agreement takes numpy's median (the mean of
    the two middle values of an even count; NaN if any value is NaN); an occluder shades a
    candidate when its interval ``[rel − baseline/r − margin, rel + margin]`` holds the
    candidate's ``rel``
    (what :func:`~agent.planning.free_space.vouched_no_return` finds by sorting)."""
    near, far, sigmas, margin_m, signal_floor, noise_floor = constants[:6]
    pan_tol, shadow_near, margin_rad, baseline = constants[6:]
    n = flag.size
    start = np.zeros(n)
    end = np.zeros(n)
    hit = np.zeros(n, dtype=np.bool_)
    vouched = np.zeros(n, dtype=np.bool_)
    known = has_point.copy()
    candidate = np.zeros(n, dtype=np.bool_)
    no_return = np.zeros(n, dtype=np.bool_)
    any_candidate = False
    for k in range(n):
        f, hp, r = flag[k], has_point[k], range_m[k]
        if f == 0 and hp:
            sig = sigma_m[k] if math.isfinite(sigma_m[k]) else math.inf
            e = r - (sigmas * sig + margin_m)
            cap = far - margin_m
            end[k] = cap if e > cap else e  # np.minimum: NaN propagates
            hit[k] = True
        elif f == 3 and hp and r > far and intensity_a[k] >= signal_floor:
            end[k] = far - margin_m
        if hp and (f == 4 or f == 5 or (f == 3 and r < near)):
            hit[k] = True
        no_return[k] = f == 1 and not hp
        candidate[k] = intensity_a[k] < noise_floor and (no_return[k] or f == 2)
        any_candidate = any_candidate or candidate[k]
    if not (told_known and n and any_candidate):
        return start, end, hit, vouched, known
    model = told_rad
    # The told headings must agree with the headings the returns measured.
    off = np.empty(n)
    m = 0
    nan = False
    for k in range(n):
        if has_point[k]:
            off[m] = abs(_wrap_angle(heading[k] - model[k]))
            nan = nan or math.isnan(off[m])
            m += 1
    if m:
        if nan:
            return start, end, hit, vouched, known
        ordered = np.sort(off[:m])
        h = m // 2
        median = ordered[h] if m % 2 else (ordered[h - 1] + ordered[h]) / 2.0
        if not median <= pan_tol:
            return start, end, hit, vouched, known
    for k in range(n):
        if not (has_point[k] and not candidate[k]):
            heading[k] = _wrap_angle(model[k])
        known[k] = True
    # vouched_no_return: headings relative to the first, unwrapped around the sweep.
    rel = np.empty(n)
    top = -math.inf
    for k in range(n):
        rel[k] = _wrap_angle(heading[k] - heading[0])
        if math.isnan(rel[k]) or math.isnan(top):
            top = math.nan
        elif rel[k] > top:
            top = rel[k]
    low = np.empty(n)
    high = np.empty(n)
    n_occ = 0
    for k in range(n):
        if (has_point[k] or no_return[k]) and not candidate[k]:
            r = max(range_m[k], near) if math.isfinite(range_m[k]) else near
            high[n_occ] = rel[k] + margin_rad
            low[n_occ] = rel[k] - baseline / r - margin_rad
            n_occ += 1
    for k in range(n):
        if not (candidate[k] and rel[k] + shadow_near + margin_rad <= top):
            continue
        shaded = False
        for o in range(n_occ):
            if low[o] <= rel[k] and high[o] >= rel[k]:
                shaded = True
                break
        if not shaded:
            vouched[k] = True
            start[k] = near
    return start, end, hit, vouched, known


def warm_up() -> None:
    """Load (or compile, on the first use on a machine) every kernel of this module, for the
    argument types :mod:`agent.planning.free_space` passes."""
    one = np.zeros(1)
    xy = np.zeros((1, 2))
    grid = np.full((4, 4), -np.inf)
    cs = (1.0, 0.0)
    add_scan(grid, 0.0, 0.0, 0.05, 0.0, 0.0, xy, one + 1.0, one, one, one + 0.1, 0.035, xy,
             np.zeros((1, 2), dtype=np.int64), True, xy, 0.0, 0.0, one, one, 1, cs, cs, cs,
             0.1, 0.07, 0.8, 0.5, 0.0)  # fmt: skip
    exits = np.zeros(2, dtype=np.int64)
    profile_ranges(grid, 0.0, 0.1, 0.1, np.ones(2), np.zeros(2), one, exits, 0.05)
    end_hits(grid, 0.0, 0.1, 0.1, np.ones(2), np.zeros(2), one, one, 0.17, 0.8, 0.5, 0.05)
    has_point, _ = beam_offsets(xy, xy, one)
    flag = np.zeros(1, dtype=np.uint8)
    constants = (0.4, 2.5, 3.0, 0.03, 7.3e-10, 1.46e-10, 0.017, 0.24, 0.017, 0.095)
    scan_evidence(one.copy(), has_point, one, one, flag, one, True, one, constants)
