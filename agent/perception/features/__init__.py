"""Feature extraction: line segments, corners, occluding edges and cylinders from one scan.

Input is the filtering stage's output for one sweep (vehicle frame, REP-103): points with
their own 2×2 covariances (range σ along the beam from the sample's intensity, eq. 6.14-6.20,
and ``r·σ_θ`` across it), range-continuous segment ids, intensities and beam geometry. The
valid samples are stacked once (:mod:`agent.perception.features.samples`, in the layout of
:mod:`agent.perception.features.rows`).

Pipeline, per segment id (a range-continuous run of samples on one or more surfaces), each
step in its module:

1. **Cylinder test** on the whole run (:mod:`agent.perception.features.cylinders`, with
   the circle fits of :mod:`agent.perception.features.circles`).
2. Otherwise **split and merge** into straight pieces
   (:mod:`agent.perception.features.split_merge`); chopped-up curves and circles that are
   one cylinder get the cylinder test again (:mod:`agent.perception.features.surfaces`).
3. Each piece is fitted by **weighted total least squares**
   (:mod:`agent.perception.features.lines`).
4. **Corners** and **occluding edges** (:mod:`agent.perception.features.extraction`);
   **reflectivity** of every feature (:mod:`agent.perception.features.reflectivity`).

A feature's kinds, parameters and covariances: :mod:`agent.perception.features.model`; the
thresholds: :mod:`agent.perception.features.settings`. The inner loops run compiled, each
in a ``*_kernels`` module beside the code it serves (see :mod:`agent.compiled`).
"""

from __future__ import annotations

from agent.perception.features import (
    circle_kernels,
    cylinder_kernels,
    extraction_kernels,
    line_kernels,
    reflectivity_kernels,
    sample_kernels,
    split_merge_kernels,
)
from agent.perception.features.circles import fit_circle
from agent.perception.features.extraction import extract_features
from agent.perception.features.lines import fit_line
from agent.perception.features.model import Feature, FeatureKind, feature_to_dict
from agent.perception.features.settings import FeatureSettings

__all__ = [
    "Feature",
    "FeatureKind",
    "FeatureSettings",
    "extract_features",
    "feature_to_dict",
    "fit_circle",
    "fit_line",
    "warm_up",
]


def warm_up() -> None:
    """Load the feature extractor's compiled kernels (see :func:`agent.perception.warm_up`)."""
    sample_kernels.warm_up()
    line_kernels.warm_up()
    circle_kernels.warm_up()
    cylinder_kernels.warm_up()
    extraction_kernels.warm_up()
    reflectivity_kernels.warm_up()
    split_merge_kernels.warm_up()
