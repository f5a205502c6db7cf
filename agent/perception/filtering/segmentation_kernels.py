"""The compiled loops of the validation gates (:mod:`agent.perception.filtering.gates`) and
the segmentation along the scan line (:mod:`agent.perception.filtering.segmentation`): the
gates, the two-sided linear predictions, the breaks between samples and the numbering of
runs, and both steps in one call. Written in numpy, the filter spent a quarter of a
millisecond per scan in call overhead (see :mod:`agent.compiled`); the gates and the
selections around the kernels, a dozen more calls, another 0.15 ms with the caches cold
between scans. The tests check the predictions against ``numpy.polyfit``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled


def read_only(a: NDArray[Any]) -> NDArray[Any]:
    """``a``, or a read-only view of it: the kernels then see the arrays of a decoded
    message (read-only) whoever calls them, and have one signature, loaded by ``warm_up``,
    rather than one to compile for each mix of writable and read-only arrays."""
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


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


@compiled
def gate_flags(
    range_m: FloatArray,
    intensity: FloatArray,
    min_intensity: float,
    near: float,
    far: float,
    codes: NDArray[np.uint8],
) -> NDArray[np.uint8]:
    """Per-sample flags from the gates alone (see ``gates.validation_gates``); ``codes``
    the flags for (valid, no reading, low SNR, out of range). A range outside [near, far]
    is out of range, an intensity below ``min_intensity`` low SNR, a range that is not
    finite no reading, each reason overriding the one before."""
    flags = np.empty(range_m.size, dtype=np.uint8)
    for i in range(range_m.size):
        r = range_m[i]
        flag = codes[0]
        if r < near or r > far:
            flag = codes[3]
        if intensity[i] < min_intensity:
            flag = codes[2]
        if not math.isfinite(r):
            flag = codes[1]
        flags[i] = flag
    return flags


@compiled
def segment_flags(
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity: FloatArray,
    flags: NDArray[np.uint8],
    window: int,
    gate_chi2: float,
    slope_per_step: float,
    intensity_ratio_gate: float,
    max_gap: int,
    min_run: int,
    valid: int,
    mixed: int,
    isolated: int,
) -> tuple[NDArray[np.uint8], NDArray[np.int32]]:
    """The segmentation of the samples flagged ``valid`` (see ``segmentation.segment_scan``):
    (flags, with ``mixed`` or ``isolated`` for the samples of runs too short; segment ids,
    -1 where dropped). The valid samples' variances and range-corrected intensities are
    ``σ²`` and ``I·r²``; :func:`scan_breaks` and :func:`label_runs` do the rest."""
    n = range_m.size
    out = flags.copy()
    segment = np.full(n, -1, dtype=np.int32)
    m = 0
    for i in range(n):
        if flags[i] == valid:
            m += 1
    if m == 0:
        return out, segment
    idx = np.empty(m, dtype=np.int64)
    r = np.empty(m)
    var = np.empty(m)
    corrected = np.empty(m)
    k = 0
    for i in range(n):
        if flags[i] == valid:
            idx[k] = i
            r[k] = range_m[i]
            var[k] = sigma_m[i] * sigma_m[i]
            corrected[k] = intensity[i] * (r[k] * r[k])  # the 1/r² of eq. 6.10 taken out
            k += 1
    steps = np.empty(max(m - 1, 0), dtype=np.int64)
    for k in range(m - 1):
        steps[k] = idx[k + 1] - idx[k]
    breaks = scan_breaks(
        r, var, corrected, steps, window, gate_chi2, slope_per_step, intensity_ratio_gate,
        max_gap,
    )  # fmt: skip
    runs, code = label_runs(r, breaks, min_run, mixed, isolated)
    for k in range(m):
        segment[idx[k]] = runs[k]
        if code[k] != 0:
            out[idx[k]] = code[k]
    return out, segment


@compiled
def gate_and_segment(
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity: FloatArray,
    min_intensity: float,
    near: float,
    far: float,
    gate_codes: NDArray[np.uint8],
    window: int,
    gate_chi2: float,
    slope_per_step: float,
    intensity_ratio_gate: float,
    max_gap: int,
    min_run: int,
    mixed: int,
    isolated: int,
) -> tuple[NDArray[np.uint8], NDArray[np.int32]]:
    """:func:`gate_flags`, then :func:`segment_flags` (the arguments as theirs): one call."""
    flags = gate_flags(range_m, intensity, min_intensity, near, far, gate_codes)
    return segment_flags(
        range_m, sigma_m, intensity, flags, window, gate_chi2, slope_per_step,
        intensity_ratio_gate, max_gap, min_run, gate_codes[0], mixed, isolated,
    )  # fmt: skip


def warm_up() -> None:
    """Load the gates' and the segmentation's kernels for the arrays of a decoded
    ``calibrated_scan`` message (read-only; compiling them on the first use on this
    machine)."""
    m = 8
    r = np.ones(m)
    r.flags.writeable = False
    steps = np.ones(m - 1, dtype=np.int64)
    breaks = scan_breaks(r, r * 1e-6, r, steps, 4, 16.0, 0.1, 1.3, 2)
    label_runs(r, breaks, 3, 4, 5)
    codes = read_only(np.arange(4, dtype=np.uint8))
    flags = gate_flags(r, r, 0.5, 0.4, 2.5, codes)
    flags.flags.writeable = False
    segment_flags(r, r, r, flags, 4, 16.0, 0.1, 1.3, 2, 3, 0, 4, 5)
    gate_and_segment(r, r, r, 0.5, 0.4, 2.5, codes, 4, 16.0, 0.1, 1.3, 2, 3, 4, 5)
