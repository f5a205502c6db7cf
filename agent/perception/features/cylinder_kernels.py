"""The compiled loop of the cylinder test (:mod:`agent.perception.features.cylinders`): how
far a plane's intensity profile misses the samples' intensities (why compiled:
:mod:`agent.compiled`)."""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled
from agent.perception.features.rows import (
    BX,
    BY,
    OX,
    OY,
    RANGE,
    REFL,
    VX,
    VY,
    WINT,
    example_rows,
)


@compiled
def plane_intensity_misfit(
    rows: FloatArray, start: int, stop: int, alpha: float, rho: float
) -> tuple[int, float, float]:
    """The log intensities of samples [start, stop) about one plane's profile (see
    ``agent.perception.features.cylinders.Cylinders._plane``): (count, largest |z|, Σ z²) of
    ``z = (log(I t²/(S cos θ)) − log cos(viewing angle) − λ) / σ``, λ their weighted mean,
    over the samples with a known intensity seen from the plane's front or back.

    ``t`` is where the beam meets the plane (x·cos α + y·sin α = ρ), the model's range, as
    in the circle fit (:func:`agent.perception.features.circle_kernels.circle_model`): the
    measured range would bring its own noise, 2σ_r/r, into every log intensity (1-2 % at
    1.5-2 m), the circle's residuals would be free of it and the plane's not, and the
    comparison of the two would lean toward the circle. Where the beam runs nearly along
    the plane (t meaningless) the measured range stays.
    """
    c, s = math.cos(alpha), math.sin(alpha)
    count = 0
    sw = swg = 0.0
    n = stop - start
    g = np.zeros(n)
    w = np.zeros(n)
    for i in range(start, stop):
        cos_view = abs(rows[VX, i] * c + rows[VY, i] * s)
        wi = rows[WINT, i]
        rng = rows[RANGE, i]
        if wi > 0.0 and cos_view > 0.0 and rng > 0.0:
            denom = rows[BX, i] * c + rows[BY, i] * s
            t = rng
            if abs(denom) > 0.05:
                meet = (rho - (rows[OX, i] * c + rows[OY, i] * s)) / denom
                if meet > 0.0:
                    t = meet
            k = i - start
            g[k] = math.log(rows[REFL, i] * (t / rng) ** 2 / cos_view)
            w[k] = wi
            count += 1
            sw += wi
            swg += wi * g[k]
    if count == 0:
        return 0, 0.0, 0.0
    lam = swg / sw
    max_z = chi2 = 0.0
    for k in range(n):
        if w[k] > 0.0:
            z = (g[k] - lam) * math.sqrt(w[k])
            max_z = max(max_z, abs(z))
            chi2 += z * z
    return count, max_z, chi2


@compiled
def convex(rows: FloatArray, start: int, stop: int, cx: float, cy: float) -> bool:
    """The centre (cx, cy) lies farther from the sensor than most of samples [start, stop)
    (see ``agent.perception.features.cylinders.Cylinders._convex``)."""
    beyond = 0
    for i in range(start, stop):
        if math.hypot(cx - rows[OX, i], cy - rows[OY, i]) > rows[RANGE, i]:
            beyond += 1
    return 2 * beyond > stop - start


def warm_up() -> None:
    """Load the cylinder test's kernel (compiling it on the first use on this machine)."""
    rows = example_rows()
    plane_intensity_misfit(rows, 0, rows.shape[1], 0.0, 1.3)
    convex(rows, 0, rows.shape[1], 1.3, 0.0)
