"""The compiled loops of split and merge (:mod:`agent.perception.features.split_merge`): where
to split a piece, and where to put the boundary between two.

In numpy each is a dozen or more small calls (prefix sums, the two sides' scatter, the
residuals of both lines near the boundary): with the caches cold between scans, a scan with
a split spent 0.2 ms more on them than compiled (why compiled: :mod:`agent.compiled`). Each
kernel computes what the method it serves documents, in the same order of operations as its
numpy formulation; the residuals' products with the lines are BLAS's, as numpy's ``@`` takes
them (numba calls the same routines), so the splits are the same to the last bit.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled
from agent.perception.features.rows import CXX, CYY, MIN_VARIANCE_M2, ONE, X, Y, example_rows


@compiled
def _first_minimum(cost: FloatArray) -> int:
    """numpy's ``argmin``: the first smallest value, or the first NaN."""
    best = 0
    for k in range(cost.size):
        if math.isnan(cost[k]):
            return k
        if cost[k] < cost[best]:
            best = k
    return best


@compiled
def _smaller_eigenvalue(cum: FloatArray, k: int, total: bool) -> float:
    """The smaller eigenvalue of the weighted scatter of the first ``k + 1`` points
    (column ``k`` of the prefix sums ``cum``), or with ``total`` of the points after them."""
    last = cum.shape[1] - 1
    sw, sx, sy = cum[0, k], cum[1, k], cum[2, k]
    sxx, syy, sxy = cum[3, k], cum[4, k], cum[5, k]
    if total:
        sw, sx, sy = cum[0, last] - sw, cum[1, last] - sx, cum[2, last] - sy
        sxx, syy, sxy = cum[3, last] - sxx, cum[4, last] - syy, cum[5, last] - sxy
    cxx = sxx - sx * sx / sw
    cyy = syy - sy * sy / sw
    cxy = sxy - sx * sy / sw
    d = cxx - cyy
    return float(0.5 * (cxx + cyy) - math.sqrt(0.25 * (d * d) + cxy * cxy))


@compiled
def _prefix_moments(rows: FloatArray, start: int, stop: int, w: FloatArray) -> FloatArray:
    """(6, count) prefix sums of w, wx, wy, wx·x, wy·y, wx·y about the first sample."""
    count = stop - start
    x0, y0 = rows[X, start], rows[Y, start]  # keeps the prefix sums well conditioned
    cum = np.empty((6, count))  # prefix sums of w, wx, wy, wx·x, wy·y, wx·y
    for k in range(count):
        x, y = rows[X, start + k] - x0, rows[Y, start + k] - y0
        wx, wy = w[k] * x, w[k] * y
        terms = (w[k], wx, wy, wx * x, wy * y, wx * y)
        for row in range(6):
            cum[row, k] = terms[row] if k == 0 else cum[row, k - 1] + terms[row]
    return cum


@compiled
def best_split(rows: FloatArray, start: int, stop: int, w: FloatArray) -> int:
    """Split position (``SplitMerge._best_split``): left [start, k), right [k, stop), ≥ 2
    points each, of least summed cost, each side's the smaller eigenvalue of its weighted
    scatter (weights ``w``) from prefix sums of weighted moments about the first sample."""
    count = stop - start
    cum = _prefix_moments(rows, start, stop, w)
    cost = np.empty(count - 3)  # the first k = 2 .. count − 2 points on the left
    for j in range(count - 3):
        cost[j] = _smaller_eigenvalue(cum, j + 1, False) + _smaller_eigenvalue(cum, j + 1, True)
    return start + 2 + _first_minimum(cost)


@compiled
def two_line_gain(
    rows: FloatArray, start: int, stop: int, w: FloatArray, min_side: int
) -> tuple[int, float, float]:
    """The best split of [start, stop) into two lines with at least ``min_side`` samples
    each (``SplitMerge._bent``): (k, one line's cost, the two lines' summed cost), each cost
    the smaller eigenvalue of the weighted scatter (weights ``w``, the χ² of a line through
    those samples with the weights held fixed); (−1, 0, 0) when the span is too short."""
    count = stop - start
    if count < 2 * min_side or min_side < 2:
        return -1, 0.0, 0.0
    cum = _prefix_moments(rows, start, stop, w)
    whole = _smaller_eigenvalue(cum, count - 1, False)
    best_k, best = -1, math.inf
    for j in range(min_side - 1, count - min_side):  # the first j + 1 samples on the left
        cost = _smaller_eigenvalue(cum, j, False) + _smaller_eigenvalue(cum, j, True)
        if cost < best:
            best_k, best = start + j + 1, cost
    return best_k, whole, best


@compiled
def _normal_z2(xy1: FloatArray, cov3: FloatArray, rho: float, c: float, s: float) -> FloatArray:
    """Squared residuals over σ along the normal (c, s) of the line at distance ρ."""
    line = np.empty(3)
    line[0], line[1], line[2] = -rho, c, s
    d = line @ xy1
    along = np.empty(3)
    along[0], along[1], along[2] = c * c, c * s, s * s
    var = along @ cov3
    z2 = np.empty(d.size)
    for i in range(d.size):
        v = var[i]
        if v < MIN_VARIANCE_M2:  # (np.maximum's rule: NaN stays NaN)
            v = MIN_VARIANCE_M2
        z2[i] = d[i] * d[i] / v
    return z2


@compiled
def boundary(
    rows: FloatArray,
    lo: int,
    hi: int,
    rho_p: float,
    c_p: float,
    s_p: float,
    rho_q: float,
    c_q: float,
    s_q: float,
) -> int:
    """The boundary k in [lo, hi] between two lines (``SplitMerge._refine_boundary``):
    samples [lo, k) on the first, [k, hi) on the second, of least summed squared residuals
    over σ along each line's normal."""
    xy1 = rows[ONE : Y + 1, lo:hi].copy()
    cov3 = rows[CXX : CYY + 1, lo:hi].copy()
    zp = _normal_z2(xy1, cov3, rho_p, c_p, s_p)
    zq = _normal_z2(xy1, cov3, rho_q, c_q, s_q)
    n = hi - lo
    head = np.empty(n + 1)  # Σ zp before k
    head[0] = 0.0
    for k in range(n):
        head[k + 1] = zp[k] if k == 0 else head[k] + zp[k]
    tail = np.empty(n + 1)  # Σ zq from k on, summed from the end
    tail[n] = 0.0
    for k in range(n - 1, -1, -1):
        tail[k] = zq[k] if k == n - 1 else tail[k + 1] + zq[k]
    cost = np.empty(n + 1)
    for k in range(n + 1):
        cost[k] = head[k] + tail[k]
    return lo + _first_minimum(cost)


def warm_up() -> None:
    """Load the split-and-merge kernels (compiling them on the first use on this machine)."""
    rows = example_rows()
    m = rows.shape[1]
    best_split(rows, 0, m, np.ones(m))
    two_line_gain(rows, 0, m, np.ones(m), 2)
    boundary(rows, 2, m - 2, 1.0, 1.0, 0.0, 1.0, 1.0, 0.0)
