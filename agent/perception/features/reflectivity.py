"""Reflectivity of every feature from intensity, range and incidence (eq. 6.10-6.11 inverted).

Each usable sample gives ``I_s·r² / (S·cos(viewing angle)·cos θ)`` on the fitted surface
(S the calibrated signal constant); a feature's reflectivity is the median over its
surfaces' samples.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.perception.features import reflectivity_kernels
from agent.perception.features.lines import Line
from agent.perception.features.samples import Samples
from agent.perception.features.settings import FeatureSettings
from agent.perception.features.surfaces import Surface


class Reflectivities:
    """Reflectivities of one scan's fitted surfaces (remembered per surface)."""

    def __init__(self, s: Samples, settings: FeatureSettings) -> None:
        self.s = s
        self.settings = settings
        self._refl: dict[tuple[int, int], FloatArray] = {}

    def per_sample(self, item: Surface) -> FloatArray:
        """Usable per-sample reflectivities ``I_s·r² / (S·cos(viewing angle)·cos θ)``.

        Eq. 6.10-6.11 inverted. A Lambertian surface sends light toward the detector in
        proportion to the cosine of the *viewing* angle: between the fitted surface normal
        and the direction to the detector's viewpoint, a baseline (9.5 cm) to the side of
        the centre of scanning. (The beam's own incidence differs from it by up to d/r, 5° at 1 m:
        under 1 % on a plane seen nearly square-on, a quarter on a cylinder's flank at 70°.)
        """
        key = (item.start, item.stop)
        cached = self._refl.get(key)
        if cached is not None:
            return cached
        rows, min_cos = self.s.rows, self.settings.reflectivity_min_cos_incidence
        if isinstance(item, Line):
            out = reflectivity_kernels.line_reflectivities(
                rows, item.start, item.stop, item.alpha, min_cos
            )
        else:  # on a circle: the normal where each beam meets it (see circles.Meeting)
            out = reflectivity_kernels.circle_reflectivities(
                rows, item.start, item.stop, item.cx, item.cy, item.r, min_cos
            )
        self._refl[key] = out
        return out

    def of(self, *items: Surface) -> float:
        """The median of the items' usable per-sample reflectivities; NaN when too few."""
        values = [self.per_sample(it) for it in items]
        joined = values[0] if len(values) == 1 else np.concatenate(values)
        if joined.size < self.settings.reflectivity_min_samples:
            return math.nan
        return float(reflectivity_kernels.median(joined))
