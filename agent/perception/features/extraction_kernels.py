"""The compiled arithmetic of corners (:mod:`agent.perception.features.extraction`).

A corner's covariance is four 2×2 matrix products: in numpy, each call costs several
microseconds with the caches cold between scans, a corner 35 µs more than compiled (why
compiled: :mod:`agent.compiled`). The products are BLAS's, as numpy's ``@`` takes them
(numba calls the same routines), so the corners are those of the numpy formulation to the
last bit.
"""

from __future__ import annotations

import numpy as np

from agent.arrays import FloatArray
from agent.compiled import compiled


@compiled
def intersection(
    c1: float,
    s1: float,
    rho1: float,
    cov1: FloatArray,
    c2: float,
    s2: float,
    rho2: float,
    cov2: FloatArray,
) -> tuple[bool, float, float, FloatArray]:
    """Intersection of the lines ``x cos α_k + y sin α_k = ρ_k`` (``c_k``, ``s_k`` their
    normals' cosines and sines) and its covariance from both lines' (α, ρ) covariances
    ``cov_k`` (2, 2): (ok, x, y, covariance (2, 2)); ok False for (nearly) parallel lines.

    Solve A x = ρ with A = [[cos α₁, sin α₁], [cos α₂, sin α₂]]; ∂x/∂ρ_k = A⁻¹ e_k and
    ∂x/∂α_k = −A⁻¹ e_k (−sin α_k x + cos α_k y). The lines come from disjoint samples, so
    their errors are independent: Σ = J₁ Σ₁ J₁ᵀ + J₂ Σ₂ J₂ᵀ.
    """
    det = c1 * s2 - s1 * c2
    if abs(det) < 1e-9:
        return False, 0.0, 0.0, np.zeros((2, 2))
    # Columns of A⁻¹: k1 = (s2, −c2)/det, k2 = (−s1, c1)/det.
    k1x, k1y, k2x, k2y = s2 / det, -c2 / det, -s1 / det, c1 / det
    x = k1x * rho1 + k2x * rho2
    y = k1y * rho1 + k2y * rho2
    d1 = -s1 * x + c1 * y
    d2 = -s2 * x + c2 * y
    j1 = np.empty((2, 2))  # ∂(x, y)/∂(α₁, ρ₁)
    j1[0, 0], j1[0, 1], j1[1, 0], j1[1, 1] = -k1x * d1, k1x, -k1y * d1, k1y
    j2 = np.empty((2, 2))
    j2[0, 0], j2[0, 1], j2[1, 0], j2[1, 1] = -k2x * d2, k2x, -k2y * d2, k2y
    return True, x, y, j1 @ cov1 @ j1.T + j2 @ cov2 @ j2.T


def warm_up() -> None:
    """Load the corner kernel (compiling it on the first use on this machine)."""
    cov = np.eye(2)
    intersection(1.0, 0.0, 1.0, cov, 0.0, 1.0, 1.0, cov)
