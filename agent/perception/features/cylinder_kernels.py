"""The compiled loop of the cylinder test (:mod:`agent.perception.features.cylinders`): how
far a plane's intensity profile misses the samples' intensities (why compiled:
:mod:`agent.compiled`)."""

from __future__ import annotations

import math

from agent.arrays import FloatArray
from agent.compiled import compiled
from agent.perception.features.rows import OX, OY, RANGE, REFL, VX, VY, WINT, example_rows


@compiled
def plane_intensity_misfit(
    rows: FloatArray, start: int, stop: int, alpha: float
) -> tuple[int, float, float]:
    """The log intensities of samples [start, stop) about one plane's profile (see
    ``agent.perception.features.cylinders.Cylinders._plane``): (count, largest |z|, Σ z²) of
    ``z = (log(I r²/(S cos θ)) − log cos(viewing angle) − λ) / σ``, λ their weighted mean,
    over the samples with a known intensity seen from the plane's front or back."""
    c, s = math.cos(alpha), math.sin(alpha)
    count = 0
    sw = swg = 0.0
    for i in range(start, stop):
        cos_view = abs(rows[VX, i] * c + rows[VY, i] * s)
        wi = rows[WINT, i]
        if wi > 0.0 and cos_view > 0.0:
            count += 1
            sw += wi
            swg += wi * math.log(rows[REFL, i] / cos_view)
    if count == 0:
        return 0, 0.0, 0.0
    lam = swg / sw
    max_z = chi2 = 0.0
    for i in range(start, stop):
        cos_view = abs(rows[VX, i] * c + rows[VY, i] * s)
        wi = rows[WINT, i]
        if wi > 0.0 and cos_view > 0.0:
            z = (math.log(rows[REFL, i] / cos_view) - lam) * math.sqrt(wi)
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
    plane_intensity_misfit(rows, 0, rows.shape[1], 0.0)
    convex(rows, 0, rows.shape[1], 1.3, 0.0)
