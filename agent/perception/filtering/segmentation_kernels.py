"""The compiled loops of the segmentation along the scan line
(:mod:`agent.perception.filtering.segmentation`): the two-sided linear predictions, the
breaks between samples and the numbering of runs. Written in numpy, the filter spent a
quarter of a millisecond per scan in call overhead (see :mod:`agent.compiled`). The tests
check the predictions against ``numpy.polyfit``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled


@compiled
def linear_predictions(
    r: FloatArray, var: FloatArray, window: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Weighted straight-line predictions of each sample from its neighbours on either side
    (see ``agent.perception.filtering.segmentation.segment_scan``).

    Returns ``(forward, forward_var, backward, backward_var)``: sample k predicted from
    samples k-window..k-1 and from k+1..k+window (NaN where there are not enough), each
    the intercept of the fit weighted by ``1/var`` with the index as abscissa, with its
    variance ``S_xx / (S_w S_xx − S_x²)``.
    """
    n = r.size
    fwd = np.full(n, np.nan)
    fvar = np.full(n, np.nan)
    bwd = np.full(n, np.nan)
    bvar = np.full(n, np.nan)
    if n <= window:
        return fwd, fvar, bwd, bvar
    for k in range(n):
        for side in range(2):
            if (side == 0 and k < window) or (side == 1 and k >= n - window):
                continue
            sw = sx = sxx = sy = sxy = 0.0
            for j in range(1, window + 1):
                i, x = (k - j, -float(j)) if side == 0 else (k + j, float(j))
                wi = 1.0 / var[i]
                sw += wi
                sx += wi * x
                sxx += wi * x * x
                sy += wi * r[i]
                sxy += wi * x * r[i]
            det = sw * sxx - sx * sx
            if side == 0:
                fwd[k], fvar[k] = (sxx * sy - sx * sxy) / det, sxx / det
            else:
                bwd[k], bvar[k] = (sxx * sy - sx * sxy) / det, sxx / det
    return fwd, fvar, bwd, bvar


@compiled
def scan_breaks(
    r: FloatArray,
    var: FloatArray,
    corrected: FloatArray,
    steps: NDArray[np.int64],
    window: int,
    gate_chi2: float,
    slope_per_step: float,
    intensity_ratio_gate: float,
    max_gap: int,
) -> BoolArray:
    """Where the scan breaks between valid samples j and j + 1 (see
    ``agent.perception.filtering.segmentation.segment_scan``): each disagrees with the
    prediction from the other side, the range changes faster than ``r · slope_per_step``
    per scan step (plus 5σ), the range-corrected intensity ``corrected`` changes by more
    than the ratio gate, or more than ``max_gap`` samples are missing between them
    (``steps`` the scan steps between neighbours).
    """
    n = r.size
    fwd, fvar, bwd, bvar = linear_predictions(r, var, window)
    breaks = np.zeros(max(n - 1, 0), dtype=np.bool_)
    for j in range(n - 1):
        # A missing prediction (NaN, near the ends) cannot disagree.
        right_bad = (r[j + 1] - fwd[j + 1]) ** 2 / (var[j + 1] + fvar[j + 1]) > gate_chi2
        left_bad = (r[j] - bwd[j]) ** 2 / (var[j] + bvar[j]) > gate_chi2
        limit = min(r[j], r[j + 1]) * slope_per_step * steps[j]
        too_steep = abs(r[j + 1] - r[j]) > limit + 5.0 * math.sqrt(var[j] + var[j + 1])
        ratio = corrected[j + 1] / corrected[j]
        jump = not (ratio < intensity_ratio_gate and ratio > 1.0 / intensity_ratio_gate)
        breaks[j] = (right_bad and left_bad) or too_steep or jump or steps[j] > max_gap + 1
    return breaks


@compiled
def label_runs(
    r: FloatArray, breaks: BoolArray, min_run: int, mixed: int, isolated: int
) -> tuple[NDArray[np.int32], NDArray[np.uint8]]:
    """Number the runs between ``breaks`` that have at least ``min_run`` samples 0, 1, ...
    (-1 for the others), and give each sample of a shorter run the code ``mixed`` when its
    range lies strictly between the ranges of the samples either side of its run, else
    ``isolated`` (0 for the samples of kept runs)."""
    n = r.size
    segment = np.full(n, -1, dtype=np.int32)
    code = np.zeros(n, dtype=np.uint8)
    label = 0
    start = 0
    for stop in range(1, n + 1):
        if stop < n and not breaks[stop - 1]:
            continue
        if stop - start >= min_run:
            segment[start:stop] = label
            label += 1
        else:
            before = r[start - 1] if start > 0 else math.nan
            after = r[stop] if stop < n else math.nan
            if math.isnan(before):
                lo = hi = after
            elif math.isnan(after):
                lo = hi = before
            else:
                lo, hi = min(before, after), max(before, after)
            for i in range(start, stop):
                code[i] = mixed if lo < r[i] < hi else isolated
        start = stop
    return segment, code


def warm_up() -> None:
    """Load the segmentation's kernels (compiling them on the first use on this machine)."""
    m = 8
    r = np.ones(m)
    steps = np.ones(m - 1, dtype=np.int64)
    breaks = scan_breaks(r, r * 1e-6, r, steps, 4, 16.0, 0.1, 1.3, 2)
    label_runs(r, breaks, 3, 4, 5)
