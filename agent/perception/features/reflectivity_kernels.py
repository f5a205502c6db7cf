"""The compiled loops of the reflectivity estimates (:mod:`agent.perception.features.reflectivity`).

Each feature's reflectivity is a median over its samples' estimates: in numpy a dozen small
calls per feature (the viewing angle, the selections, the median's partition), each costing
microseconds with the caches cold between scans; here one call per surface and one for the
median (why compiled: :mod:`agent.compiled`). Each kernel computes what its docstring says,
in the same order of operations as the formulas in
:mod:`agent.perception.features.reflectivity` and ``circles.Meeting``.
"""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled
from agent.perception.features.rows import BX, BY, OX, OY, REFL, VX, VY, example_rows


@compiled
def _usable(rows: FloatArray, start: int, cos_view: FloatArray, min_cos: float) -> FloatArray:
    """``REFL / cos_view`` of the samples ``start + k`` seen at ``cos_view[k] ≥ min_cos``,
    where finite."""
    out = np.empty(cos_view.size)
    kept = 0
    for k in range(cos_view.size):
        if cos_view[k] >= min_cos:
            rho = rows[REFL, start + k] / cos_view[k]
            if math.isfinite(rho):
                out[kept] = rho
                kept += 1
    return out[:kept].copy()


@compiled
def line_reflectivities(
    rows: FloatArray, start: int, stop: int, alpha: float, min_cos: float
) -> FloatArray:
    """Usable per-sample reflectivities of samples [start, stop) on the plane of normal
    angle ``alpha`` (see ``Reflectivities.per_sample``): the viewing angle's cosine
    ``|v·n|``, samples seen at ``min_cos`` or more, finite estimates."""
    c, s = math.cos(alpha), math.sin(alpha)
    cos_view = np.empty(stop - start)
    for k in range(stop - start):
        cos_view[k] = abs(rows[VX, start + k] * c + rows[VY, start + k] * s)
    return _usable(rows, start, cos_view, min_cos)


@compiled
def circle_reflectivities(
    rows: FloatArray, start: int, stop: int, cx: float, cy: float, r: float, min_cos: float
) -> FloatArray:
    """Usable per-sample reflectivities of samples [start, stop) on the circle (cx, cy, r):
    the viewing angle's cosine ``u·v`` (0 where negative) with ``u`` the outward normal
    where the sample's beam meets the circle (``circles.Meeting``)."""
    cos_view = np.empty(stop - start)
    for k in range(stop - start):
        i = start + k
        bx, by = rows[BX, i], rows[BY, i]
        ocx = cx - rows[OX, i]
        ocy = cy - rows[OY, i]
        big_b = bx * ocx + by * ocy
        disc = big_b * big_b - (ocx * ocx + ocy * ocy) + r * r
        if disc < 0.0:  # (np.maximum's rule: NaN stays NaN)
            disc = 0.0
        t = big_b - math.sqrt(disc)
        fx = t * bx - ocx
        fy = t * by - ocy
        flen = math.hypot(fx, fy)
        if flen < 1e-12:
            flen = 1e-12
        cos_k = fx / flen * rows[VX, i] + fy / flen * rows[VY, i]
        cos_view[k] = 0.0 if cos_k < 0.0 else cos_k
    return _usable(rows, start, cos_view, min_cos)


@compiled
def median(values: FloatArray) -> float:
    """The median of (finite) values: the middle one, or the mean of the middle two."""
    ordered = np.sort(values)
    m = ordered.size
    return float(0.5 * (ordered[(m - 1) // 2] + ordered[m // 2]))


def warm_up() -> None:
    """Load the reflectivity kernels (compiling them on the first use on this machine)."""
    rows = example_rows()
    m = rows.shape[1]
    median(line_reflectivities(rows, 0, m, math.pi, 0.2))
    circle_reflectivities(rows, 0, m, 1.3, 0.0, 0.2, 0.2)
