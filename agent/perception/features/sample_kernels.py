"""The compiled loop that picks a scan's usable samples and stacks them (the layout of
:mod:`agent.perception.features.rows`, used by :mod:`agent.perception.features.samples`;
why compiled: :mod:`agent.compiled`): one call per scan instead of some thirty small numpy
calls, each of which costs several microseconds with the caches cold between scans."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.compiled import compiled
from agent.perception.features.model import IndexArray
from agent.perception.features.rows import (
    BX,
    BY,
    CXX,
    CXY2,
    CYY,
    INT,
    ONE,
    OX,
    OY,
    RANGE,
    REFL,
    ROWS,
    VARB,
    VX,
    VY,
    WINT,
    X,
    Y,
)


@compiled
def stacked_samples(
    points: FloatArray,
    cov4: FloatArray,
    segment: NDArray[np.integer[Any]],
    flag: NDArray[np.integer[Any]],
    origin: FloatArray,
    theta: FloatArray,
    range_m: FloatArray,
    intensity: FloatArray,
    signal_constant: float,
    baseline_m: float,
    noise_current_A: float,
    intensity_model_sigma: float,
    neighbour_correlation: float,
) -> tuple[IndexArray, FloatArray, FloatArray, IndexArray, FloatArray]:
    """One scan's usable samples, stacked and grouped by segment id (see
    :func:`agent.perception.features.samples.prepare_samples`).

    Of the n samples, those with flag 0 and a segment id of at least 0 whose geometry is
    usable: finite, a beam with a direction, a positive semi-definite covariance (to
    rounding). ``points`` and ``origin`` (n, 2), ``cov4`` (n, 4) the covariances flattened,
    ``theta`` the scan angles, ``range_m`` (the beam's length where not positive),
    ``intensity`` the signal currents; ``noise_current_A`` NaN when intensities are not to
    be fitted (their weights are then 0).

    Returns (index (m,) into the scan, rows (ROWS, m) in the layout of
    :mod:`agent.perception.features.rows`, their scan angles (m,), the bounds of the runs
    (runs + 1,): run k is [bounds[k], bounds[k + 1]), and pair_cov (m − 1,) the covariance
    of the range errors of samples k and k + 1). The samples are in segment-id order, scan
    order within each id; a run's end samples get no intensity weight.
    """
    n = segment.size
    work = np.empty((ROWS, n))
    picked = np.empty(n, dtype=np.intp)
    m = 0
    fit_intensity = not math.isnan(noise_current_A)
    model_var = intensity_model_sigma * intensity_model_sigma
    for i in range(n):
        if flag[i] != 0 or segment[i] < 0:
            continue
        x, y = points[i, 0], points[i, 1]
        cxx, cxy2, cyy = cov4[i, 0], cov4[i, 1] + cov4[i, 2], cov4[i, 3]
        ox, oy = origin[i, 0], origin[i, 1]
        th = theta[i]
        work[ONE, m], work[X, m], work[Y, m] = 1.0, x, y
        work[CXX, m], work[CXY2, m], work[CYY, m] = cxx, cxy2, cyy
        work[OX, m], work[OY, m] = ox, oy
        length = math.hypot(x - ox, y - oy)
        bx, by = (x - ox) / length, (y - oy) / length
        work[BX, m], work[BY, m] = bx, by
        work[VARB, m] = bx * (bx * cxx + by * cxy2) + by * by * cyy
        r = range_m[i] if range_m[i] > 0.0 else length  # NaN compares False
        work[RANGE, m] = r
        inten = intensity[i]
        work[INT, m] = inten
        cos_t, sin_t = math.cos(th), math.sin(th)
        work[REFL, m] = inten * r * r / (signal_constant * cos_t) if inten > 0.0 else math.nan
        # The head faces the beam turned back by the scan angle; the detector's viewpoint
        # lies a baseline to its left.
        hx, hy = bx * cos_t + by * sin_t, by * cos_t - bx * sin_t
        vx, vy = ox - baseline_m * hy - x, oy + baseline_m * hx - y
        v_len = math.hypot(vx, vy)
        work[VX, m], work[VY, m] = vx / v_len, vy / v_len
        w_int = 0.0
        if fit_intensity and inten > 0.0:
            rel = noise_current_A / inten
            w_int = 1.0 / (rel * rel + model_var)
            if not math.isfinite(w_int):
                w_int = 0.0
        work[WINT, m] = w_int
        finite = math.isfinite(x + y + cxx + cxy2 + cyy + ox + oy + bx + by + th)
        if (
            finite
            and length > 0.0
            and cxx > 0.0
            and cyy > 0.0
            and 4.0 * cxx * cyy * (1.0 + 1e-9) >= cxy2 * cxy2
        ):
            picked[m] = i
            m += 1  # kept: the next sample fills the next column
    # Grouped by segment id, scan order within each (the ids are normally in scan order).
    column = np.arange(m)
    for k in range(1, m):
        if segment[picked[k]] < segment[picked[k - 1]]:
            ids = np.empty(m, dtype=np.int64)
            for j in range(m):
                ids[j] = segment[picked[j]]
            column = np.argsort(ids, kind="mergesort")
            break
    index = np.empty(m, dtype=np.intp)
    angles = np.empty(m)
    rows = np.empty((ROWS, m))
    for k in range(m):
        j = column[k]
        index[k] = picked[j]
        angles[k] = theta[picked[j]]
        for row in range(ROWS):
            rows[row, k] = work[row, j]
    bounds = np.empty(m + 1, dtype=np.intp)
    runs = 0
    for k in range(m):
        if k == 0 or segment[index[k]] != segment[index[k - 1]]:
            bounds[runs] = k
            runs += 1
    bounds[runs] = m
    # The spot at either end of a run straddles the run's edge (see prepare_samples): its
    # intensity is not fitted.
    for k in range(runs):
        rows[WINT, bounds[k]] = 0.0
        rows[WINT, bounds[k + 1] - 1] = 0.0
    # Range errors of neighbouring samples (consecutive in the scan) are correlated by the
    # detection filter: covariance ρ₁·σ_k·σ_{k+1} along the beams.
    pair_cov = np.empty(max(m - 1, 0))
    for k in range(m - 1):
        if index[k + 1] - index[k] == 1:
            sigma_k, sigma_next = math.sqrt(rows[VARB, k]), math.sqrt(rows[VARB, k + 1])
            pair_cov[k] = neighbour_correlation * sigma_k * sigma_next
        else:
            pair_cov[k] = 0.0
    return index, rows, angles, bounds[: runs + 1].copy(), pair_cov


def warm_up() -> None:
    """Load :func:`stacked_samples` for the arrays of a decoded ``filtered_scan`` message
    (read-only, int32 segment ids, uint8 flags; compiling it on the first use on this
    machine)."""
    n = 8
    xy, cov4, origin = np.zeros((n, 2)), np.zeros((n, 4)), np.ones((n, 2))
    segment, flag = np.zeros(n, dtype=np.int32), np.zeros(n, dtype=np.uint8)
    theta, range_m, intensity = np.zeros(n), np.ones(n), np.ones(n)
    arrays = (xy, cov4, segment, flag, origin, theta, range_m, intensity)
    for a in arrays:
        a.flags.writeable = False
    stacked_samples(*arrays, 1.0, 0.1, 1e-10, 0.02, 0.1)
