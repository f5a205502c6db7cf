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
from numpy.typing import ArrayLike, NDArray

from agent.arrays import FloatArray
from agent.perception.filtering import segmentation_kernels
from agent.perception.filtering.flags import SampleFlag
from agent.perception.filtering.gates import GATE_CODES
from agent.perception.filtering.segmentation_kernels import read_only
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
    Compiled: :func:`segmentation_kernels.segment_flags`.
    """
    r, sigma, intensity = _arrays(range_m, sigma_m, intensity_A)
    return segmentation_kernels.segment_flags(
        r, sigma, intensity, read_only(np.asarray(flags, dtype=np.uint8)),
        settings.window, settings.gate_chi2, _slope_per_step(settings),
        settings.intensity_ratio_gate, settings.max_gap, settings.min_run,
        SampleFlag.VALID.value, SampleFlag.MIXED.value, SampleFlag.ISOLATED.value,
    )  # fmt: skip


def gate_and_segment(
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity_A: FloatArray,
    noise_current_A: float,
    settings: FilterSettings,
) -> tuple[NDArray[np.uint8], NDArray[np.int32]]:
    """The validation gates, then segmentation: per-sample ``(flags, segment)``.

    One compiled call (:func:`segmentation_kernels.gate_and_segment`) for
    :func:`~agent.perception.filtering.gates.validation_gates` then :func:`segment_scan`.
    """
    near, far = settings.depth_of_field_m
    r, sigma, intensity = _arrays(range_m, sigma_m, intensity_A)
    return segmentation_kernels.gate_and_segment(
        r, sigma, intensity, settings.min_snr * noise_current_A, near, far,
        GATE_CODES, settings.window, settings.gate_chi2, _slope_per_step(settings),
        settings.intensity_ratio_gate, settings.max_gap, settings.min_run,
        SampleFlag.MIXED.value, SampleFlag.ISOLATED.value,
    )  # fmt: skip


def _slope_per_step(settings: FilterSettings) -> float:
    """The steepest range change per scan step, over the range (``max_incidence_deg``)."""
    return settings.sample_spacing_rad * math.tan(math.radians(settings.max_incidence_deg))


def _arrays(
    range_m: ArrayLike, sigma_m: ArrayLike, intensity_A: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The per-sample arrays as the kernels take them: float64, read-only."""
    r, sigma, intensity = (
        read_only(np.asarray(a, dtype=np.float64)) for a in (range_m, sigma_m, intensity_A)
    )
    return r, sigma, intensity
