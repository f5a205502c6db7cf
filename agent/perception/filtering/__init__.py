"""Filtering: validation gates, segmentation at range discontinuities, motion compensation.

Every sample leaves with a :class:`SampleFlag` saying why it was kept or dropped. The steps,
each in its module:

1. **Validation gates** per sample (:mod:`agent.perception.filtering.gates`).
2. **Segmentation** along the scan line, with the intensity validation gate
   (:mod:`agent.perception.filtering.segmentation`).
3. **Motion compensation**: each sample placed with the vehicle pose at its own time; off for
   the whole scan, and said so, when the vehicle state is missing or too old at the scan's
   samples (:mod:`agent.perception.filtering.placement`).

The thresholds: :mod:`agent.perception.filtering.settings`. The inner loops run compiled,
each in a ``*_kernels`` module beside the code it serves (see
:mod:`agent.compiled`).
"""

from __future__ import annotations

from agent.perception.filtering import placement_kernels, segmentation_kernels
from agent.perception.filtering.flags import SampleFlag
from agent.perception.filtering.gates import validation_gates
from agent.perception.filtering.placement import PlacedPoints, PoseHistory, place_samples
from agent.perception.filtering.segmentation import gate_and_segment, segment_scan
from agent.perception.filtering.settings import FilterSettings

__all__ = [
    "FilterSettings",
    "PlacedPoints",
    "PoseHistory",
    "SampleFlag",
    "gate_and_segment",
    "place_samples",
    "segment_scan",
    "validation_gates",
    "warm_up",
]


def warm_up() -> None:
    """Load the filter's compiled kernels (see :func:`agent.perception.warm_up`)."""
    segmentation_kernels.warm_up()
    placement_kernels.warm_up()
