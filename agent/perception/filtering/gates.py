"""Validation gates: whether each sample, on its own, can be trusted at all.

A position reading must exist; the signal must stand ``min_snr`` times above the noise
current (σ_u = I_n/I_s, eq. 6.14: a noise-only sample in a missing part fails here); the
range must lie in the depth of field.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.perception.filtering import segmentation_kernels
from agent.perception.filtering.flags import SampleFlag
from agent.perception.filtering.settings import FilterSettings

# The flags the gates give, in the order the compiled gates take them (read-only, as the
# kernels take every array: see segmentation_kernels.read_only).
GATE_CODES = segmentation_kernels.read_only(
    np.array(
        [SampleFlag.VALID, SampleFlag.NO_READING, SampleFlag.LOW_SNR, SampleFlag.OUT_OF_RANGE],
        dtype=np.uint8,
    )
)


def validation_gates(
    range_m: FloatArray, intensity_A: FloatArray, noise_current_A: float, settings: FilterSettings
) -> NDArray[np.uint8]:
    """Per-sample flags from the gates alone (VALID, NO_READING, LOW_SNR, OUT_OF_RANGE).

    Compiled (:func:`segmentation_kernels.gate_flags`): a range outside the depth of field
    is out of range, a signal below ``min_snr`` noise currents low SNR, a range that is not
    finite no reading, each reason overriding the one before.
    """
    near, far = settings.depth_of_field_m
    return segmentation_kernels.gate_flags(
        segmentation_kernels.read_only(np.asarray(range_m, dtype=np.float64)),
        segmentation_kernels.read_only(np.asarray(intensity_A, dtype=np.float64)),
        settings.min_snr * noise_current_A, near, far, GATE_CODES,
    )  # fmt: skip
