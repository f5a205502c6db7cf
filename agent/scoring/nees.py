"""Normalised estimation error squared (NEES) and its consistency interval over runs.

For an error ``e`` (d,) and the covariance ``P`` (d, d) the estimate claims,
``NEES = eᵀ P⁻¹ e``; for a consistent estimator it is χ²-distributed with ``d`` degrees of
freedom, mean ``d``. Bar-Shalom, Li and Kirubarajan, *Estimation with Applications to
Tracking and Navigation* (2001), section 5.4.2: the average over ``N`` independent runs,
times ``N``, is χ² with ``N·d`` degrees of freedom, so the two-sided 95 % interval of the
average is ``χ²_{N·d}(0.025, 0.975) / N`` (for d = 2 and N = 100: [1.63, 2.41]).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.stats import chi2

from agent.arrays import FloatArray

__all__ = ["average_interval", "nees"]


def nees(error: npt.ArrayLike, covariance: npt.ArrayLike) -> FloatArray:
    """NEES of each error against its covariance.

    Parameters
    ----------
    error
        (n, d) errors (estimate − truth), in the state's units.
    covariance
        (n, d, d) the estimates' covariances.

    Returns
    -------
    numpy.ndarray
        (n,) ``eᵀ P⁻¹ e``; NaN where ``P`` is singular or not finite.
    """
    e = np.asarray(error, dtype=np.float64)
    P = np.asarray(covariance, dtype=np.float64)
    if e.ndim != 2 or P.shape != (*e.shape, e.shape[1]):
        raise ValueError(
            f"error (n, d) and covariance (n, d, d) expected, got {e.shape}, {P.shape}"
        )
    out = np.full(e.shape[0], np.nan)
    ok = np.isfinite(P).all(axis=(1, 2)) & np.isfinite(e).all(axis=1)
    if ok.any():
        det = np.linalg.det(P[ok])
        good = np.flatnonzero(ok)[det > 0.0]
        if good.size:
            solved = np.linalg.solve(P[good], e[good][:, :, None])[:, :, 0]
            out[good] = np.einsum("ij,ij->i", e[good], solved)
    return out


def average_interval(dof: int, runs: int, probability: float = 0.95) -> tuple[float, float]:
    """The two-sided ``probability`` interval of the average NEES over ``runs`` independent
    runs of a consistent estimator with ``dof`` degrees of freedom."""
    if dof < 1 or runs < 1:
        raise ValueError(f"dof and runs must be at least 1, got {dof}, {runs}")
    tail = 0.5 * (1.0 - probability)
    bounds = np.asarray(chi2.ppf([tail, 1.0 - tail], dof * runs), dtype=np.float64) / runs
    return float(bounds[0]), float(bounds[1])
