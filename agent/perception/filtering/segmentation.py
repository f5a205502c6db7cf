"""Segmentation along the scan line: breaks at discontinuities, transition samples flagged.

The chapter's suggestion of a scan-line Kalman filter with an intensity validation gate. A
Kalman filter on range along the scan with a constant-slope model and each sample's own
variance is, over a short memory, a weighted linear prediction; here it runs over the whole
scan (compiled, :mod:`agent.perception.filtering.segmentation_kernels`), in both
directions: each valid sample is predicted from the ``window`` valid samples before it and
from the ``window`` after it, and tested with the exact innovation variance (χ², 1 dof).
Between two neighbours the scan breaks when the left sample disagrees with the prediction
from the right *and* the right one with the prediction from the left, when the range changes
faster than any surface seen at ``max_incidence_deg`` could, or when the range-corrected
intensity jumps by more than ``intensity_ratio_gate`` (the intensity validation gate:
intensity changes smoothly along one surface, and blended samples between two surfaces show
it). Runs shorter than ``min_run`` samples are transition samples: ``MIXED`` when their
ranges lie between the surfaces on either side (the footprint and the detection filter
blend the two surfaces' currents into phantom ranges), ``ISOLATED`` otherwise.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.perception.filtering import segmentation_kernels
from agent.perception.filtering.flags import SampleFlag
from agent.perception.filtering.gates import validation_gates
from agent.perception.filtering.settings import FilterSettings


def segment_scan(
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity_A: FloatArray,
    flags: NDArray[np.uint8],
    settings: FilterSettings,
) -> tuple[NDArray[np.uint8], NDArray[np.int32]]:
    """Break the scan at discontinuities; flag transition samples. Returns (flags, segment).

    ``segment`` numbers the surviving runs 0, 1, ... in scan order, -1 for dropped samples.
    """
    flags = flags.copy()
    segment = np.full(range_m.shape, -1, dtype=np.int32)
    idx = np.flatnonzero(flags == SampleFlag.VALID)
    if idx.size == 0:
        return flags, segment
    r = range_m[idx]
    var = sigma_m[idx] ** 2
    corrected = intensity_A[idx] * r**2  # intensity with the 1/r² of eq. 6.10 taken out
    slope_per_step = settings.sample_spacing_rad * math.tan(
        math.radians(settings.max_incidence_deg)
    )
    breaks = segmentation_kernels.scan_breaks(
        r, var, corrected, np.diff(idx), settings.window, settings.gate_chi2,
        slope_per_step, settings.intensity_ratio_gate, settings.max_gap,
    )  # fmt: skip
    runs, code = segmentation_kernels.label_runs(
        r, breaks, settings.min_run, SampleFlag.MIXED.value, SampleFlag.ISOLATED.value
    )
    segment[idx] = runs
    dropped = np.flatnonzero(code)
    if dropped.size:
        flags[idx[dropped]] = code[dropped]
    return flags, segment


def gate_and_segment(
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity_A: FloatArray,
    noise_current_A: float,
    settings: FilterSettings,
) -> tuple[NDArray[np.uint8], NDArray[np.int32]]:
    """The validation gates, then segmentation: per-sample ``(flags, segment)``."""
    flags = validation_gates(range_m, intensity_A, noise_current_A, settings)
    return segment_scan(range_m, sigma_m, intensity_A, flags, settings)
