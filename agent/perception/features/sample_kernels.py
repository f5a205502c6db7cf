"""The compiled loop that fills the stacked rows of a scan's samples (the layout of
:mod:`agent.perception.features.rows`, used by :mod:`agent.perception.features.samples`;
why compiled: :mod:`agent.compiled`)."""

from __future__ import annotations

import math

import numpy as np

from agent.arrays import BoolArray, FloatArray
from agent.compiled import compiled
from agent.perception.features.rows import (
    BX,
    BY,
    CXX,
    CXY2,
    CYY,
    INT,
    ONE,
    OX,
    OY,
    RANGE,
    REFL,
    ROWS,
    VARB,
    VX,
    VY,
    WINT,
    X,
    Y,
)


@compiled
def sample_rows(
    points: FloatArray,
    cov4: FloatArray,
    origin: FloatArray,
    theta: FloatArray,
    range_m: FloatArray,
    intensity: FloatArray,
    signal_constant: float,
    baseline_m: float,
    noise_current_A: float,
    intensity_model_sigma: float,
) -> tuple[FloatArray, BoolArray]:
    """The stacked rows (see :mod:`agent.perception.features.rows`) of m samples, and which
    of them are usable: finite geometry, a beam with a direction and a positive semi-definite
    covariance (to rounding).

    ``points`` and ``origin`` (m, 2), ``cov4`` (m, 4) the covariances flattened, ``theta``
    the scan angles, ``range_m`` (the beam's length where not positive), ``intensity`` the
    signal currents; ``noise_current_A`` NaN when intensities are not to be fitted (their
    weights are then 0).
    """
    m = points.shape[0]
    rows = np.empty((ROWS, m))
    good = np.empty(m, dtype=np.bool_)
    fit_intensity = not math.isnan(noise_current_A)
    model_var = intensity_model_sigma * intensity_model_sigma
    for i in range(m):
        x, y = points[i, 0], points[i, 1]
        cxx, cxy2, cyy = cov4[i, 0], cov4[i, 1] + cov4[i, 2], cov4[i, 3]
        ox, oy = origin[i, 0], origin[i, 1]
        th = theta[i]
        rows[ONE, i], rows[X, i], rows[Y, i] = 1.0, x, y
        rows[CXX, i], rows[CXY2, i], rows[CYY, i] = cxx, cxy2, cyy
        rows[OX, i], rows[OY, i] = ox, oy
        length = math.hypot(x - ox, y - oy)
        bx, by = (x - ox) / length, (y - oy) / length
        rows[BX, i], rows[BY, i] = bx, by
        rows[VARB, i] = bx * (bx * cxx + by * cxy2) + by * by * cyy
        r = range_m[i] if range_m[i] > 0.0 else length  # NaN compares False
        rows[RANGE, i] = r
        inten = intensity[i]
        rows[INT, i] = inten
        cos_t, sin_t = math.cos(th), math.sin(th)
        rows[REFL, i] = inten * r * r / (signal_constant * cos_t) if inten > 0.0 else math.nan
        # The head faces the beam turned back by the scan angle; the detector's viewpoint
        # lies a baseline to its left.
        hx, hy = bx * cos_t + by * sin_t, by * cos_t - bx * sin_t
        vx, vy = ox - baseline_m * hy - x, oy + baseline_m * hx - y
        v_len = math.hypot(vx, vy)
        rows[VX, i], rows[VY, i] = vx / v_len, vy / v_len
        w_int = 0.0
        if fit_intensity and inten > 0.0:
            rel = noise_current_A / inten
            w_int = 1.0 / (rel * rel + model_var)
            if not math.isfinite(w_int):
                w_int = 0.0
        rows[WINT, i] = w_int
        finite = math.isfinite(x + y + cxx + cxy2 + cyy + ox + oy + bx + by + th)
        good[i] = (
            finite
            and length > 0.0
            and cxx > 0.0
            and cyy > 0.0
            and 4.0 * cxx * cyy * (1.0 + 1e-9) >= cxy2 * cxy2
        )
    return rows, good


def warm_up() -> None:
    """Load :func:`sample_rows` (compiling it on the first use on this machine)."""
    m = 8
    cols = np.zeros((m, 2))
    sample_rows(cols, np.zeros((m, 4)), cols.copy(), np.zeros(m), np.ones(m), np.ones(m),
                1.0, 0.1, 1e-10, 0.02)  # fmt: skip
