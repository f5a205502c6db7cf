"""Reflectivity of every feature from intensity, range and incidence (eq. 6.10-6.11 inverted).

Each usable sample gives ``I_s·r² / (S·cos(viewing angle)·cos θ)`` on the fitted surface
(S the calibrated signal constant); a feature's reflectivity is the median over its
surfaces' samples.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.perception.features.circles import Meeting
from agent.perception.features.lines import Line
from agent.perception.features.rows import BX, BY, OX, OY, REFL, VX, VY
from agent.perception.features.samples import Samples
from agent.perception.features.settings import FeatureSettings
from agent.perception.features.surfaces import Surface


def _median(values: FloatArray) -> float:
    m = values.size
    part = np.partition(values, [(m - 1) // 2, m // 2])
    return 0.5 * float(part[(m - 1) // 2] + part[m // 2])


def _cos_view_line(rows: FloatArray, alpha: float) -> FloatArray:
    """Cosine of each sample's viewing angle on a plane of normal angle ``alpha``."""
    return np.asarray(
        np.abs(rows[VX] * math.cos(alpha) + rows[VY] * math.sin(alpha)), dtype=np.float64
    )


def _cos_view(rows: FloatArray, item: Surface) -> FloatArray:
    """Cosine of each sample's viewing angle on the fitted surface (0 where it faces away).

    The surface normal is the line's, or the circle's where the sample's beam meets it.
    """
    if isinstance(item, Line):
        return _cos_view_line(rows, item.alpha)
    meet = Meeting.of(rows[OX], rows[OY], rows[BX], rows[BY], item.cx, item.cy, item.r)
    ux, uy = meet.ux, meet.uy
    return np.asarray(np.maximum(ux * rows[VX] + uy * rows[VY], 0.0), dtype=np.float64)


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
        rows = self.s.rows[:, item.start : item.stop]
        cos_inc = _cos_view(rows, item)
        usable = cos_inc >= self.settings.reflectivity_min_cos_incidence
        rho = rows[REFL][usable] / cos_inc[usable]
        out = np.asarray(rho[np.isfinite(rho)], dtype=np.float64)
        self._refl[key] = out
        return out

    def of(self, *items: Surface) -> float:
        """The median of the items' usable per-sample reflectivities; NaN when too few."""
        values = [self.per_sample(it) for it in items]
        joined = values[0] if len(values) == 1 else np.concatenate(values)
        if joined.size < self.settings.reflectivity_min_samples:
            return math.nan
        return _median(joined)
