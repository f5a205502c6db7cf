"""Validation gates: whether each sample, on its own, can be trusted at all.

A position reading must exist; the signal must stand ``min_snr`` times above the noise
current (σ_u = I_n/I_s, eq. 6.14: a noise-only sample in a missing part fails here); the
range must lie in the depth of field.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.perception.filtering.flags import SampleFlag
from agent.perception.filtering.settings import FilterSettings


def validation_gates(
    range_m: FloatArray, intensity_A: FloatArray, noise_current_A: float, settings: FilterSettings
) -> NDArray[np.uint8]:
    """Per-sample flags from the gates alone (VALID, NO_READING, LOW_SNR, OUT_OF_RANGE)."""
    flags = np.full(range_m.shape, SampleFlag.VALID, dtype=np.uint8)
    near, far = settings.depth_of_field_m
    with np.errstate(invalid="ignore"):
        out = (range_m < near) | (range_m > far)
        weak = intensity_A < settings.min_snr * noise_current_A
    flags[out] = SampleFlag.OUT_OF_RANGE
    flags[weak] = SampleFlag.LOW_SNR
    flags[~np.isfinite(range_m)] = SampleFlag.NO_READING
    return flags
