"""The compiled loops of the controller's safety check (:mod:`agent.control.clearance`).

Written in numpy (the reference formulations in :mod:`agent.control.clearance`, which the
tests compare these with), composing the local state cost 4.3 ms (p50) per vector with 40
obstacles in view, nearly all of it in distances from every open cell of the window to every
nearby obstacle, and a command 1.3 ms, a third of it moving 56 perimeter points through 21
steps of 20 motions and looking each up. Here:

* :func:`mark_capsules` visits, per capsule, only the cells of its bounding box;
* :func:`first_blocked` moves the perimeter points step by step and stops each motion at
  its first step with a point outside known clear space, computing poses and the blind-band
  test as it goes (no (m, n, p) arrays);
* :func:`record_profile`, :func:`record_silence`, :func:`record_outline` and
  :func:`compose_cells` do in one pass per cell what took a dozen whole-array operations
  (0.3-0.5 ms each, for the free-space memory and the navigation field's map, then the
  window); :func:`outline_gaps` finds the obstacles that reach the outline;
* :func:`first_closer` checks the motions against the obstacles already reaching the
  outline (intruders), exactly, step by step and only up to each motion's first blocked
  step: in numpy, over every step of every motion at once, it took 0.73 ms a call, half
  of all the controller's time in the random rooms of ``evaluate``, where a coasting
  track's grown inflation often reaches the outline; here about 10 µs;
* :func:`max_scales` solves the braking rule for a set of twists (ten numpy operations,
  30 µs a call, two calls a command; 7 µs here).

Cell indices: ``state[iy, ix]`` with ``ix = floor((x − origin_x)/cell_m)`` (``odom`` x) and
``iy`` likewise along y.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled, compiled_inline
from agent.control.geometry_kernels import arc_offset

IntArray = NDArray[np.int64]

_CLEAR, _BAND, _UNSEEN = 1, 2, 3


@compiled_inline
def _cell_span(lo_m: float, hi_m: float, origin: float, cell_m: float, n: int) -> tuple[int, int]:
    """The cells ``[lo, hi)`` of a grid axis of ``n`` cells that ``[lo_m, hi_m]`` reaches;
    none for a span off the grid or not a number. Clamped to the grid before the conversion
    to integers: a float beyond int64's range has no integer, numba's conversion of one is
    undefined, and a loop over such a span ran for ever (an environment vector with a
    mover at 1e188 m/s; ``tests/unit/control/test_clearance_kernels_bounds.py``)."""
    lo = (lo_m - origin) / cell_m
    hi = (hi_m - origin) / cell_m + 1.0
    if not (lo < n and hi > 0.0 and lo <= hi):
        return 0, 0
    return math.floor(max(lo, 0.0)), math.floor(min(hi, float(n)))


@compiled_inline
def _capsule_box(
    ax: float, ay: float, bx: float, by: float, r: float,
    origin_x: float, origin_y: float, cell_m: float, nx: int, ny: int,
) -> tuple[int, int, int, int]:  # fmt: skip
    """The cells ``[lo_x, hi_x) × [lo_y, hi_y)`` of the grid that the capsule of core
    ``(ax, ay) → (bx, by)`` and radius ``r`` can reach."""
    lo_x, hi_x = _cell_span(min(ax, bx) - r, max(ax, bx) + r, origin_x, cell_m, nx)
    lo_y, hi_y = _cell_span(min(ay, by) - r, max(ay, by) + r, origin_y, cell_m, ny)
    return lo_x, hi_x, lo_y, hi_y


@compiled_inline
def _suspect(lc: float, ls: float, lt: float, lq: float, suspect_after_s: float) -> bool:
    """A possible surface was seen in the cell (``ls``) since it was last seen clear
    (``lc``), under the outline (``lt``) or silent (``lq``), and not too long ago."""
    return ls > max(lc, lt, lq) and ls >= suspect_after_s


@compiled_inline
def _known(
    lc: float, ls: float, lt: float, lq: float,
    remember_after_s: float, suspect_after_s: float, there_after_s: float,
) -> bool:  # fmt: skip
    """The cell is known clear by the memory (rules (a) to (c) of
    :mod:`agent.control.clearance`): seen clear or silent after ``remember_after_s``, or
    under the outline after ``there_after_s``, and no possible surface seen since."""
    return (
        lc >= remember_after_s or lq >= remember_after_s or lt >= there_after_s
    ) and not _suspect(lc, ls, lt, lq, suspect_after_s)


@compiled_inline
def _within(
    cx: float, cy: float, ax: float, ay: float, ex: float, ey: float, den: float, r: float
) -> bool:
    """The point ``(cx, cy)`` lies within ``r`` of the segment from ``(ax, ay)`` along
    ``(ex, ey)`` (``den`` its squared length)."""
    t = 0.0
    if den > 0.0:
        t = ((cx - ax) * ex + (cy - ay) * ey) / den
        t = min(max(t, 0.0), 1.0)
    dx = cx - ax - t * ex
    dy = cy - ay - t * ey
    return dx * dx + dy * dy <= r * r


@compiled
def mark_capsules(
    hit: BoolArray,
    open_cells: BoolArray,
    origin_x: float,
    origin_y: float,
    cell_m: float,
    a: FloatArray,
    b: FloatArray,
    reach: FloatArray,
) -> None:
    """Set ``hit`` (ny, nx) where an open cell's centre lies within ``reach + half a cell's
    diagonal`` of a capsule's core ``a[k] → b[k]`` (k, 2)."""
    ny, nx = hit.shape
    half_diag = cell_m * math.sqrt(0.5)
    for k in range(a.shape[0]):
        ax, ay, bx, by = a[k, 0], a[k, 1], b[k, 0], b[k, 1]
        r = reach[k] + half_diag
        lo_x, hi_x, lo_y, hi_y = _capsule_box(ax, ay, bx, by, r, origin_x, origin_y, cell_m, nx, ny)
        ex, ey = bx - ax, by - ay
        den = ex * ex + ey * ey
        for iy in range(lo_y, hi_y):
            cy = origin_y + (iy + 0.5) * cell_m
            for ix in range(lo_x, hi_x):
                if not open_cells[iy, ix] or hit[iy, ix]:
                    continue
                cx = origin_x + (ix + 0.5) * cell_m
                if _within(cx, cy, ax, ay, ex, ey, den, r):
                    hit[iy, ix] = True


@compiled
def forget_capsules(
    suspect_s: FloatArray,
    origin_x: float,
    origin_y: float,
    cell_m: float,
    a: FloatArray,
    b: FloatArray,
    reach: FloatArray,
) -> None:
    """Set ``suspect_s`` (ny, nx) to −inf at every cell :func:`mark_capsules` would mark
    with every cell open (the same bounding boxes and test), in place: no grid-sized masks
    (two of them and a masked assignment cost ``forget_movers_hits`` 15 µs a vector)."""
    ny, nx = suspect_s.shape
    half_diag = cell_m * math.sqrt(0.5)
    for k in range(a.shape[0]):
        ax, ay, bx, by = a[k, 0], a[k, 1], b[k, 0], b[k, 1]
        r = reach[k] + half_diag
        lo_x, hi_x, lo_y, hi_y = _capsule_box(ax, ay, bx, by, r, origin_x, origin_y, cell_m, nx, ny)
        ex, ey = bx - ax, by - ay
        den = ex * ex + ey * ey
        for iy in range(lo_y, hi_y):
            cy = origin_y + (iy + 0.5) * cell_m
            for ix in range(lo_x, hi_x):
                cx = origin_x + (ix + 0.5) * cell_m
                if _within(cx, cy, ax, ay, ex, ey, den, r):
                    suspect_s[iy, ix] = -math.inf


@compiled_inline
def _moved_cell(
    px: float, py: float, ct: float, st: float, qx: float, qy: float, x: float, y: float,
    c0: float, s0: float, origin_x: float, origin_y: float, cell_m: float,
) -> tuple[float, float, int, int]:  # fmt: skip
    """A point ``(qx, qy)`` of the vehicle (``base_link``) with the vehicle moved to
    ``(px, py)`` turned by ``(ct, st)`` (cos, sin), in ``base_link`` now ``(bx, by)``, and
    its memory cell (``ix``, ``iy``), the vehicle now at ``(x, y)`` heading ``(c0, s0)``."""
    bx = px + ct * qx - st * qy
    by = py + st * qx + ct * qy
    ix = math.floor((x + c0 * bx - s0 * by - origin_x) / cell_m)
    iy = math.floor((y + s0 * bx + c0 * by - origin_y) / cell_m)
    return bx, by, ix, iy


@compiled
def first_blocked(
    v_unit: FloatArray,
    w_unit: FloatArray,
    n_steps: int,
    step_m: float,
    outline: FloatArray,
    x: float,
    y: float,
    yaw: float,
    state: NDArray[np.uint8],
    origin_x: float,
    origin_y: float,
    cell_m: float,
    half_length_m: float,
    half_width_m: float,
    band_m: float,
) -> IntArray:
    """Per motion (m,), the first step (1 … n−1) at which a perimeter point of ``outline``
    (p, 2) lies outside known clear space: its cell ``BLOCKED``, off the grid, or ``BAND``
    with the point further than ``band_m`` from the outline at the present pose;
    ``n_steps`` if none. Poses follow the exact unicycle equations of
    :mod:`agent.control.geometry`."""
    ny, nx = state.shape
    c0, s0 = math.cos(yaw), math.sin(yaw)
    out = np.full(v_unit.shape[0], n_steps, dtype=np.int64)
    for j in range(v_unit.shape[0]):
        v, w = v_unit[j], w_unit[j]
        done = False
        for i in range(1, n_steps):
            px, py, th = arc_offset(v, w, i * step_m)
            ct, st = math.cos(th), math.sin(th)
            for q in range(outline.shape[0]):
                bx, by, ix, iy = _moved_cell(
                    px, py, ct, st, outline[q, 0], outline[q, 1], x, y, c0, s0,
                    origin_x, origin_y, cell_m,
                )  # fmt: skip
                ok = False
                if 0 <= ix < nx and 0 <= iy < ny:
                    cell = state[iy, ix]
                    if cell == _CLEAR:
                        ok = True
                    elif cell == _BAND:
                        ex = max(abs(bx) - half_length_m, 0.0)
                        ey = max(abs(by) - half_width_m, 0.0)
                        ok = ex * ex + ey * ey <= band_m * band_m
                if not ok:
                    out[j] = i
                    done = True
                    break
            if done:
                break
    return out


@compiled
def first_unseen_ahead(
    v_unit: FloatArray,
    w_unit: FloatArray,
    n_steps: int,
    step_m: float,
    row: FloatArray,
    x: float,
    y: float,
    yaw: float,
    state: NDArray[np.uint8],
    origin_x: float,
    origin_y: float,
    cell_m: float,
) -> IntArray:
    """Per motion (m,), the first step (0 … n−1) at which a point of ``row`` (k, 2,
    ``base_link``: the points the head cannot see nearer than, ahead of the bumper) lies in
    an unknown cell (``BAND`` or ``UNSEEN``); ``n_steps`` if none, and for motions that do
    not go forward (``v_unit <= 0``). Poses follow the exact unicycle equations of
    :mod:`agent.control.geometry`."""
    ny, nx = state.shape
    c0, s0 = math.cos(yaw), math.sin(yaw)
    out = np.full(v_unit.shape[0], n_steps, dtype=np.int64)
    for j in range(v_unit.shape[0]):
        v, w = v_unit[j], w_unit[j]
        if v <= 0.0:
            continue
        done = False
        for i in range(n_steps):
            px, py, th = arc_offset(v, w, i * step_m)
            ct, st = math.cos(th), math.sin(th)
            for q in range(row.shape[0]):
                _, _, ix, iy = _moved_cell(
                    px, py, ct, st, row[q, 0], row[q, 1], x, y, c0, s0, origin_x, origin_y,
                    cell_m,
                )  # fmt: skip
                if 0 <= ix < nx and 0 <= iy < ny:
                    cell = state[iy, ix]
                    if cell >= _BAND:  # BAND or UNSEEN: unknown
                        out[j] = i
                        done = True
                        break
            if done:
                break
    return out


@compiled
def fan_box(
    ranges: FloatArray,
    bearings: FloatArray,
    yaw: float,
    step_rad: float,
    head_x: float,
    head_y: float,
    depth_m: float,
) -> tuple[float, float, float, float]:
    """``(min_x, min_y, max_x, max_y)`` of the centre of scanning ``(head_x, head_y)`` and
    the ends, ``depth_m`` past each lit sector's range (``ranges`` > 0), of the two edges of
    every lit sector (``bearings`` + ``yaw`` ± half ``step_rad``): the box
    :func:`agent.control.clearance.profile_box_reference` finds in numpy."""
    lo_x = hi_x = head_x
    lo_y = hi_y = head_y
    half = 0.5 * step_rad
    for k in range(ranges.shape[0]):
        if not ranges[k] > 0.0:
            continue
        reach = ranges[k] + depth_m
        for edge in (-half, half):
            a = yaw + bearings[k] + edge
            x = head_x + reach * math.cos(a)
            y = head_y + reach * math.sin(a)
            lo_x, hi_x = min(lo_x, x), max(hi_x, x)
            lo_y, hi_y = min(lo_y, y), max(hi_y, y)
    return lo_x, lo_y, hi_x, hi_y


@compiled
def record_profile(
    clear_s: FloatArray,
    suspect_s: FloatArray,
    stamp_s: float,
    lo_x: int,
    hi_x: int,
    lo_y: int,
    hi_y: int,
    origin_x: float,
    origin_y: float,
    cell_m: float,
    head_x: float,
    head_y: float,
    yaw: float,
    ranges: FloatArray,
    evidence: FloatArray,
    surface: FloatArray,
    step_rad: float,
    suspect_min_range_m: float,
    suspect_max_range_m: float,
    suspect_depth_m: float,
    clear_from_m: float,
) -> None:
    """Stamp ``stamp_s`` into ``clear_s`` / ``suspect_s`` (ny, nx) for the cells of the box
    ``[lo_y, hi_y) × [lo_x, hi_x)`` that the profile ``ranges`` (b,) shows clear / shows a
    possible surface in, as :func:`agent.control.clearance.rasterise_profile` defines them
    (``evidence`` is its ranges with unlit sectors outside the window at +inf; ``surface``
    (b,) is 1.0 where a sector's end may be a surface; the profile vouches only for cells
    wholly beyond ``clear_from_m``)."""
    b = ranges.shape[0]
    half_diag = cell_m * math.sqrt(0.5)
    for iy in range(lo_y, hi_y):
        dy = origin_y + (iy + 0.5) * cell_m - head_y
        for ix in range(lo_x, hi_x):
            dx = origin_x + (ix + 0.5) * cell_m - head_x
            rng = math.hypot(dx, dy)
            brg = math.atan2(dy, dx) - yaw
            centre = math.floor((brg + math.pi) / step_rad + 0.5) % b
            end = ranges[centre]
            if end <= 0.0 or rng - half_diag > end + suspect_depth_m:
                continue  # neither clear nor a possible surface
            spread = math.asin(min(1.0, half_diag / max(rng, 1e-9)))
            first = math.floor((brg - spread + math.pi) / step_rad + 0.5)
            last = math.floor((brg + spread + math.pi) / step_rad + 0.5)
            smallest = np.inf
            for k in range(first, min(last, first + b - 1) + 1):
                smallest = min(smallest, evidence[k % b])
            clear = (
                end > 0.0
                and rng > half_diag
                and rng - half_diag >= clear_from_m
                and rng + half_diag <= smallest
            )
            if clear:
                clear_s[iy, ix] = stamp_s
            elif (
                surface[centre] > 0.0
                and end >= suspect_min_range_m
                and end < suspect_max_range_m
                and rng + half_diag > end
                and rng - half_diag <= end + suspect_depth_m
            ):
                suspect_s[iy, ix] = stamp_s


@compiled
def compose_cells(
    last_clear: FloatArray,
    last_suspect: FloatArray,
    last_there: FloatArray,
    last_silent: FloatArray,
    lo_x: int,
    lo_y: int,
    n_x: int,
    n_y: int,
    origin_x: float,
    origin_y: float,
    cell_m: float,
    x: float,
    y: float,
    yaw: float,
    head_offset_m: float,
    half_length_m: float,
    half_width_m: float,
    tan_window: float,
    near_limit_m: float,
    far_limit_m: float,
    remember_after_s: float,
    suspect_after_s: float,
    there_after_s: float,
) -> tuple[NDArray[np.uint8], BoolArray]:
    """The local state's window (n_y, n_x) from cell (lo_y, lo_x) of the memory, before
    obstacles and pinholes: ``CLEAR`` (own outline, or known clear by rules (a) to (c)),
    ``BAND`` (unknown beside the window, where ``blind_band_m`` may apply), ``UNSEEN``
    (unknown in the window) or ``BLOCKED`` (a possible surface);
    and the cells obstacles may still close (known clear or band, not the outline). As
    :func:`agent.control.clearance.compose_cells_reference`."""
    state = np.zeros((n_y, n_x), dtype=np.uint8)
    open_cells = np.zeros((n_y, n_x), dtype=np.bool_)
    c, s = math.cos(yaw), math.sin(yaw)
    far2 = far_limit_m * far_limit_m
    near2 = near_limit_m * near_limit_m
    for j in range(n_y):
        Y = origin_y + (lo_y + j + 0.5) * cell_m - y
        for i in range(n_x):
            X = origin_x + (lo_x + i + 0.5) * cell_m - x
            bx = c * X + s * Y
            by = -s * X + c * Y
            fx = bx - head_offset_m
            r2 = fx * fx + by * by
            in_window = fx > 0.0 and abs(by) <= tan_window * fx and near2 <= r2 <= far2
            lc = last_clear[lo_y + j, lo_x + i]
            ls = last_suspect[lo_y + j, lo_x + i]
            lt = last_there[lo_y + j, lo_x + i]
            lq = last_silent[lo_y + j, lo_x + i]
            suspect = _suspect(lc, ls, lt, lq, suspect_after_s)
            known = _known(lc, ls, lt, lq, remember_after_s, suspect_after_s, there_after_s)
            band_ok = not known and not suspect and not in_window
            own = abs(bx) <= half_length_m and abs(by) <= half_width_m
            if own or known:
                state[j, i] = _CLEAR
            elif band_ok:
                state[j, i] = _BAND
            elif not suspect:
                state[j, i] = _UNSEEN
            open_cells[j, i] = (known or band_ok) and not own
    return state, open_cells


@compiled
def record_silence(
    silent_s: FloatArray,
    stamp_s: float,
    origin_x: float,
    origin_y: float,
    cell_m: float,
    head_x: float,
    head_y: float,
    window_yaw: float,
    tan_window: float,
    window_offset: float,
    near_m: float,
    silent_m: float,
    ranges: FloatArray,
    step_rad: float,
    last_clear: FloatArray,
    last_suspect: FloatArray,
    last_there: FloatArray,
    remember_after_s: float,
    suspect_after_s: float,
    there_after_s: float,
    pose_x: float,
    pose_y: float,
    pose_yaw: float,
    half_length: float,
    half_width: float,
) -> None:
    """Stamp ``stamp_s`` into the cells of ``silent_s`` (ny, nx) whose centre lies in the
    scan window (``|y| <= tan_window·x`` in axes at ``window_yaw``, the window's centre
    direction in ``odom``; a half-width below 90°) between ``near_m`` and ``silent_m`` from
    the centre of scanning, and over which every sector of the profile ``ranges`` (b,) the
    cell spans is silent (0) or clear past the cell. The profile's bearings are the
    vehicle's (``base_link``): a cell's is its bearing from the window's centre plus
    ``window_offset``, the centre's bearing from the heading (0: the forward window).

    And only where the way to the cell nearer than ``near_m`` is known clear: a surface
    there images off the detector, returns nothing, and hides whatever lies behind it. Along
    the cell's bearing and its two edges, every point (half a cell apart) from the centre of
    scanning to ``near_m`` is inside the vehicle's outline (pose ``pose_*``, half sides
    ``half_length``, ``half_width``) or in a cell known clear by the memory, as
    :func:`compose_cells` reads it (``last_clear``, ``last_silent`` after
    ``remember_after_s``, ``last_there`` after ``there_after_s``, no possible surface in
    ``last_suspect`` after ``suspect_after_s`` since)."""
    n_y, n_x = silent_s.shape
    b = ranges.shape[0]
    if b == 0:
        return
    half_diag = cell_m * math.sqrt(0.5)
    c, s = math.cos(window_yaw), math.sin(window_yaw)
    half = tan_window * silent_m
    xs = (head_x, head_x + c * silent_m - s * half, head_x + c * silent_m + s * half)
    ys = (head_y, head_y + s * silent_m + c * half, head_y + s * silent_m - c * half)
    lo_x, hi_x = _cell_span(min(xs), max(xs), origin_x, cell_m, n_x)
    lo_y, hi_y = _cell_span(min(ys), max(ys), origin_y, cell_m, n_y)
    for iy in range(lo_y, hi_y):
        dy = origin_y + (iy + 0.5) * cell_m - head_y
        for ix in range(lo_x, hi_x):
            dx = origin_x + (ix + 0.5) * cell_m - head_x
            fx = c * dx + s * dy
            fy = -s * dx + c * dy
            r = math.hypot(fx, fy)
            if not (fx > 0.0 and abs(fy) <= tan_window * fx and near_m <= r <= silent_m):
                continue
            brg = math.atan2(fy, fx) + window_offset
            spread = math.asin(min(1.0, half_diag / r))
            first = math.floor((brg - spread + math.pi) / step_rad + 0.5)
            last = math.floor((brg + spread + math.pi) / step_rad + 0.5)
            silent = True
            for k in range(first, last + 1):
                end = ranges[k % b]
                if end > 0.0 and end < r + half_diag:
                    silent = False
                    break
            if silent:
                silent = _near_way_clear(
                    math.atan2(dy, dx), spread, head_x, head_y, near_m, 0.5 * cell_m,
                    silent_s, last_clear, last_suspect, last_there, origin_x, origin_y,
                    cell_m, remember_after_s, suspect_after_s, there_after_s, pose_x,
                    pose_y, pose_yaw, half_length, half_width,
                )  # fmt: skip
            if silent:
                silent_s[iy, ix] = stamp_s


@compiled
def _near_way_clear(
    bearing: float,
    spread: float,
    head_x: float,
    head_y: float,
    near_m: float,
    step_m: float,
    last_silent: FloatArray,
    last_clear: FloatArray,
    last_suspect: FloatArray,
    last_there: FloatArray,
    origin_x: float,
    origin_y: float,
    cell_m: float,
    remember_after_s: float,
    suspect_after_s: float,
    there_after_s: float,
    pose_x: float,
    pose_y: float,
    pose_yaw: float,
    half_length: float,
    half_width: float,
) -> bool:
    """Whether the way from the centre of scanning out to ``near_m`` along ``bearing``
    (``odom``) and ``bearing ± spread`` is inside the outline or known clear
    (:func:`record_silence`)."""
    n_y, n_x = last_clear.shape
    cy, sy = math.cos(pose_yaw), math.sin(pose_yaw)
    n = int(near_m / step_m)
    for side in range(3):
        a = bearing + (side - 1) * spread
        ca, sa = math.cos(a), math.sin(a)
        for k in range(n + 1):
            d = k * step_m
            px, py = head_x + ca * d, head_y + sa * d
            bx = cy * (px - pose_x) + sy * (py - pose_y)
            by = -sy * (px - pose_x) + cy * (py - pose_y)
            if abs(bx) <= half_length and abs(by) <= half_width:
                continue  # the vehicle itself: nothing else is there
            ix = math.floor((px - origin_x) / cell_m)
            iy = math.floor((py - origin_y) / cell_m)
            if ix < 0 or iy < 0 or ix >= n_x or iy >= n_y:
                return False
            if not _known(
                last_clear[iy, ix], last_suspect[iy, ix], last_there[iy, ix],
                last_silent[iy, ix], remember_after_s, suspect_after_s, there_after_s,
            ):  # fmt: skip
                return False
    return True


@compiled
def record_outline(
    there_s: FloatArray,
    stamp_s: float,
    origin_x: float,
    origin_y: float,
    cell_m: float,
    x: float,
    y: float,
    yaw: float,
    half_length_m: float,
    half_width_m: float,
) -> None:
    """Stamp ``stamp_s`` into the cells of ``there_s`` (ny, nx) whose centre lies within the
    rectangle ``|x| <= half_length_m, |y| <= half_width_m`` at pose ``(x, y, yaw)``."""
    n_y, n_x = there_s.shape
    c, s = math.cos(yaw), math.sin(yaw)
    r = math.hypot(half_length_m, half_width_m)
    lo_x, hi_x = _cell_span(x - r, x + r, origin_x, cell_m, n_x)
    lo_y, hi_y = _cell_span(y - r, y + r, origin_y, cell_m, n_y)
    for iy in range(lo_y, hi_y):
        dy = origin_y + (iy + 0.5) * cell_m - y
        for ix in range(lo_x, hi_x):
            dx = origin_x + (ix + 0.5) * cell_m - x
            if abs(c * dx + s * dy) <= half_length_m and abs(-s * dx + c * dy) <= half_width_m:
                there_s[iy, ix] = stamp_s


@compiled_inline
def _segment_point(ax: float, ay: float, bx: float, by: float, px: float, py: float) -> float:
    ex, ey = bx - ax, by - ay
    den = ex * ex + ey * ey
    t = 0.0
    if den > 0.0:
        t = min(max(((px - ax) * ex + (py - ay) * ey) / den, 0.0), 1.0)
    return math.hypot(px - ax - t * ex, py - ay - t * ey)


@compiled_inline
def _cross(ox: float, oy: float, ax: float, ay: float, bx: float, by: float) -> float:
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@compiled_inline
def _rectangle_segment(ax: float, ay: float, bx: float, by: float, hx: float, hy: float) -> float:
    """The distance between the rectangle ``|x| <= hx, |y| <= hy`` and the segment
    ``(ax, ay) → (bx, by)`` in its frame; 0 where they meet. As
    :func:`agent.control.geometry.rectangle_segment_distance`, operation for operation."""
    d = min(
        math.hypot(max(abs(ax) - hx, 0.0), max(abs(ay) - hy, 0.0)),
        math.hypot(max(abs(bx) - hx, 0.0), max(abs(by) - hy, 0.0)),
    )
    for cx, cy in ((hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy)):
        d = min(d, _segment_point(ax, ay, bx, by, cx, cy))
    for ox, oy, px, py in ((hx, hy, -hx, -hy), (-hx, hy, hx, -hy)):
        d1 = _cross(ox, oy, px, py, ax, ay)
        d2 = _cross(ox, oy, px, py, bx, by)
        d3 = _cross(ax, ay, bx, by, ox, oy)
        d4 = _cross(ax, ay, bx, by, px, py)
        if d1 * d2 < 0.0 and d3 * d4 < 0.0:
            d = 0.0
    return d


@compiled
def outline_gaps(
    a: FloatArray, b: FloatArray, x: float, y: float, yaw: float, hx: float, hy: float
) -> FloatArray:
    """Distances (k,) between the outline (``|x| <= hx, |y| <= hy`` in base_link at pose
    ``x, y, yaw``) and segments ``a[k] → b[k]`` (k, 2) in ``odom``; 0 where they meet. As
    :func:`agent.control.geometry.rectangle_segment_distance`."""
    c, s = math.cos(yaw), math.sin(yaw)
    out = np.empty(a.shape[0])
    for k in range(a.shape[0]):
        ax = c * (a[k, 0] - x) + s * (a[k, 1] - y)
        ay = -s * (a[k, 0] - x) + c * (a[k, 1] - y)
        bx = c * (b[k, 0] - x) + s * (b[k, 1] - y)
        by = -s * (b[k, 0] - x) + c * (b[k, 1] - y)
        out[k] = _rectangle_segment(ax, ay, bx, by, hx, hy)
    return out


@compiled
def rectangle_segment_distances(a: FloatArray, b: FloatArray, hx: float, hy: float) -> FloatArray:
    """Distances (k,) between the rectangle ``|x| <= hx, |y| <= hy`` and segments
    ``a[k] → b[k]`` (k, 2) in its frame: what
    :func:`agent.control.geometry.rectangle_segment_distance` computes (its tests' kernel:
    no stage calls it, so :func:`warm_up` leaves it out)."""
    out = np.empty(a.shape[0])
    for k in range(a.shape[0]):
        out[k] = _rectangle_segment(a[k, 0], a[k, 1], b[k, 0], b[k, 1], hx, hy)
    return out


@compiled
def first_closer(
    v_unit: FloatArray,
    w_unit: FloatArray,
    first: IntArray,
    step_m: float,
    a: FloatArray,
    b: FloatArray,
    reach: FloatArray,
    x: float,
    y: float,
    yaw: float,
    hx: float,
    hy: float,
) -> IntArray:
    """Per motion (m,), the first step ``i`` (1 … ``first[j]`` − 1) at which the outline
    (``|x| <= hx, |y| <= hy`` in base_link) comes nearer an intruder's core ``a[k] → b[k]``
    (k, 2, ``odom``) than it is at the pose ``(x, y, yaw)`` now or than the intruder's
    ``reach`` (k,), less 1 mm; ``first[j]`` if none does before it (steps from there on do
    not matter: the motion is stopped there already). Poses as :func:`first_blocked`;
    distances as :func:`_rectangle_segment`. The numpy reference is
    :func:`agent.control.clearance.intruders_ok_reference`."""
    c, s = math.cos(yaw), math.sin(yaw)
    k = a.shape[0]
    # The cores in base_link now, and how near each may come.
    core = np.empty((k, 4))
    need = np.empty(k)
    for q in range(k):
        rx, ry = a[q, 0] - x, a[q, 1] - y
        core[q, 0] = c * rx + s * ry
        core[q, 1] = -s * rx + c * ry
        rx, ry = b[q, 0] - x, b[q, 1] - y
        core[q, 2] = c * rx + s * ry
        core[q, 3] = -s * rx + c * ry
        now = _rectangle_segment(core[q, 0], core[q, 1], core[q, 2], core[q, 3], hx, hy)
        need[q] = min(now, reach[q]) - 1e-3
    out = first.copy()
    for j in range(v_unit.shape[0]):
        v, w = v_unit[j], w_unit[j]
        for i in range(1, first[j]):
            px, py, th = arc_offset(v, w, i * step_m)
            ct, st = math.cos(th), math.sin(th)
            closer = False
            for q in range(k):
                dx, dy = core[q, 0] - px, core[q, 1] - py
                ax, ay = ct * dx + st * dy, -st * dx + ct * dy
                dx, dy = core[q, 2] - px, core[q, 3] - py
                bx, by = ct * dx + st * dy, -st * dx + ct * dy
                if not _rectangle_segment(ax, ay, bx, by, hx, hy) >= need[q]:
                    closer = True
                    break
            if closer:
                out[j] = i
                break
    return out


@compiled
def max_scales(
    v: FloatArray,
    w: FloatArray,
    d_free: FloatArray,
    radius_m: float,
    max_accel_m_s2: float,
    max_yaw_accel_rad_s2: float,
    tau_s: float,
    margin_m: float,
) -> FloatArray:
    """The largest ``λ`` in [0, 1] such that ``λ·(v[j], w[j])`` (m,) satisfies (1) of
    :mod:`agent.control.clearance` with free travel ``d_free[j]``: as
    :func:`agent.control.clearance.max_scale_reference`, operation for operation."""
    out = np.empty(v.shape[0])
    for j in range(v.shape[0]):
        av, aw = abs(v[j]), abs(w[j])
        u = av + radius_m * aw
        beta = max(av / max_accel_m_s2, aw / max_yaw_accel_rad_s2)
        room = max(d_free[j] - margin_m, 0.0)
        B = u * tau_s
        den = B + math.sqrt(B * B + 2.0 * u * beta * room)
        lam = 2.0 * room / max(den, 1e-300) if u > 0.0 else 1.0
        out[j] = min(lam, 1.0)
    return out


def warm_up() -> None:
    """Load (or compile, on the first use on a machine) every kernel of this module, for the
    argument types :mod:`agent.control.clearance` passes."""
    grid = np.zeros((4, 4), dtype=np.bool_)
    xy = np.zeros((1, 2))
    mark_capsules(grid, grid, 0.0, 0.0, 0.05, xy, xy, np.zeros(1))
    forget_capsules(np.zeros((4, 4)), 0.0, 0.0, 0.05, xy, xy, np.zeros(1))
    outline_gaps(xy, xy, 0.0, 0.0, 0.0, 0.4, 0.3)
    max_scales(np.ones(1), np.ones(1), np.ones(1), 0.5, 0.5, 2.0, 0.1, 0.03)
    first_closer(np.ones(1), np.zeros(1), np.full(1, 2), 0.05, xy, xy, np.zeros(1), 0.0, 0.0,
                 0.0, 0.4, 0.3)  # fmt: skip
    fan_box(np.ones(4), np.zeros(4), 0.0, 0.1, 0.0, 0.0, 0.15)
    times = np.full((4, 4), -np.inf)
    record_profile(times, times, 0.0, 0, 4, 0, 4, 0.0, 0.0, 0.05, 0.0, 0.0, 0.0, np.ones(4),
                   np.ones(4), np.ones(4), 1.5, 0.4, 1.5, 0.15, 0.0)  # fmt: skip
    compose_cells(times, times, times, times, 0, 0, 2, 2, 0.0, 0.0, 0.05, 0.0, 0.0, 0.0, 0.3,
                  0.4, 0.3, 0.35, 0.4, 2.5, 0.0, 0.0, 0.0)  # fmt: skip
    record_silence(times, 0.0, 0.0, 0.0, 0.05, 0.0, 0.0, 0.0, 0.35, 0.0, 0.4, 0.8, np.ones(4),
                   1.5, times, times, times, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.4, 0.3)  # fmt: skip
    record_outline(times, 0.0, 0.0, 0.0, 0.05, 0.0, 0.0, 0.0, 0.4, 0.3)
    state = np.zeros((4, 4), dtype=np.uint8)
    first_blocked(np.ones(1), np.zeros(1), 2, 0.05, xy, 0.0, 0.0, 0.0, state, 0.0, 0.0, 0.05,
                  0.4, 0.3, 0.2)  # fmt: skip
    first_unseen_ahead(np.ones(1), np.zeros(1), 2, 0.05, xy, 0.0, 0.0, 0.0, state, 0.0, 0.0,
                       0.05)  # fmt: skip
