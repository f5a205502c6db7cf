"""Time to move under a rate and an acceleration limit."""

from __future__ import annotations

import numpy as np

from agent.arrays import FloatArray

__all__ = ["rest_to_rest_s"]


def rest_to_rest_s(
    distance: FloatArray | float, rate: FloatArray | float, accel: FloatArray | float
) -> FloatArray:
    """Seconds to cover ``|distance|`` from rest to rest at most at ``rate`` and ``accel``
    (broadcast): ``2√(d/a)`` while the rate is not reached (``d ≤ v²/a``), else
    ``d/v + v/a`` (a trapezoidal profile)."""
    d = np.abs(np.asarray(distance, dtype=np.float64))
    v, a = np.asarray(rate, dtype=np.float64), np.asarray(accel, dtype=np.float64)
    return np.asarray(np.where(d <= v * v / a, 2.0 * np.sqrt(d / a), d / v + v / a), np.float64)
