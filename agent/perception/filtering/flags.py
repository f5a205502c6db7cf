"""Why each sample was kept or dropped: every sample leaves the filter with a flag."""

from __future__ import annotations

from enum import IntEnum


class SampleFlag(IntEnum):
    """Why a sample was kept or dropped."""

    VALID = 0
    NO_READING = 1  # no position reading: nothing in range, off the detector, no signal
    LOW_SNR = 2  # signal too weak for its range to be trusted (missing parts: noise only)
    OUT_OF_RANGE = 3  # outside the depth of field
    MIXED = 4  # between two surfaces at a range discontinuity (a phantom range)
    ISOLATED = 5  # too few consistent neighbours to belong to a surface
