"""The stacked per-sample matrix: one row per quantity, one column per sample.

The feature extractor stacks one scan's valid samples as the rows of one matrix (the layout
below; see :class:`agent.perception.features.samples.Samples`) and fits lines and circles to
spans of its columns; :func:`point_rows` and :func:`beam_rows` stack loose points for the
public fits. Compiled kernels take the whole stacked matrix and a span ``[start, stop)`` of
its columns rather than views, so that every call has one compiled signature (C-contiguous
float64 rows).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from agent.arrays import FloatArray

# The kernels compile the constants below in, and numba's on-disk cache notices changes to a
# kernel's own file only: after changing one, delete the kernels' caches
# (tests/unit/perception/features/test_rows.py fails while a stale one is loaded).

# Rows of the stacked per-sample matrix (see ``agent.perception.features.samples.Samples``):
# 1, x, y, C_xx, 2·C_xy, C_yy, the beam's origin and unit direction, the variance along the
# beam, range, intensity, reflectivity at normal incidence, the unit vector to the detector's
# viewpoint, and the log intensity's weight.
ROWS = 17
ONE, X, Y, CXX, CXY2, CYY, OX, OY, BX, BY, VARB = range(11)
RANGE, INT, REFL, VX, VY, WINT = range(11, ROWS)

# Smallest variance a point may have along any direction, m² ((1 µm)²): keeps weights finite
# when a covariance is (numerically) singular across the beam.
MIN_VARIANCE_M2 = 1e-12


def point_rows(points_xy: ArrayLike, covariance: ArrayLike) -> FloatArray:
    """Stacked rows for points (m, 2) and covariances (m, 2, 2)."""
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(covariance, dtype=np.float64).reshape(-1, 2, 2)
    if c.shape[0] != p.shape[0]:
        raise ValueError(f"{p.shape[0]} points but {c.shape[0]} covariances")
    rows = np.zeros((ROWS, p.shape[0]))
    rows[ONE] = 1.0
    rows[X : Y + 1] = p.T
    rows[CXX] = c[:, 0, 0]
    rows[CXY2] = c[:, 0, 1] + c[:, 1, 0]
    rows[CYY] = c[:, 1, 1]
    return rows


def beam_rows(p: FloatArray, c: FloatArray, o: FloatArray) -> FloatArray | None:
    """Stacked rows for points (m, 2), covariances, origins."""
    rows = point_rows(p, c)
    rows[OX : OY + 1] = o.T
    b = p - o
    length = np.hypot(b[:, 0], b[:, 1])
    if not np.all(length > 0.0):
        return None
    rows[BX : BY + 1] = (b / length[:, None]).T
    bx, by = rows[BX], rows[BY]
    rows[VARB] = bx * (bx * rows[CXX] + by * rows[CXY2]) + by * by * rows[CYY]
    rows[VX], rows[VY] = -bx, -by  # (no intensities here: the viewpoint is not used)
    rows[WINT] = 0.0
    return rows


def example_rows(m: int = 8) -> FloatArray:
    """Rows of ``m`` samples on a short straight piece 1 m ahead, for loading the kernels:
    the types of the arguments choose the compiled code, their values do not."""
    rows = np.zeros((ROWS, m))
    rows[ONE] = 1.0
    rows[X] = np.linspace(1.0, 1.1, m)
    rows[Y] = np.linspace(-0.1, 0.1, m)
    rows[CXX] = rows[CYY] = rows[VARB] = 1e-6
    rows[BX] = 1.0
    rows[VX] = -1.0
    rows[REFL] = rows[WINT] = 1.0
    return rows
