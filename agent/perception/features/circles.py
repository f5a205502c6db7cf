"""Weighted circle fits to samples seen along their beams (a convex surface: a cylinder).

An algebraic (Kåsa) circle first, then a weighted Gauss-Newton fit of the distances along
the radial direction, each sample's direction taken where its beam meets the circle, with
the intensities where they are known (:func:`circle_fit`). Beams grazing the circle are
left out. The iterations run compiled (:mod:`agent.perception.features.circle_kernels`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.arrays import FloatArray
from agent.perception.features import circle_kernels
from agent.perception.features.rows import beam_rows


def kasa(rows: FloatArray, start: int, stop: int) -> tuple[float, float, float] | None:
    """Weighted algebraic circle fit (Kåsa 1976) to samples [start, stop) of the stacked
    ``rows``: minimise Σ w (x²+y² + D x + E y + F)², w = 1/(C_xx + C_yy); (cx, cy, r) or
    None. Compiled (:func:`circle_kernels.kasa`): in numpy, its dozen small calls cost a
    cylinder test about 70 µs with the caches cold between scans, the kernel about 20 µs.
    """
    ok, cx, cy, r = circle_kernels.kasa(rows, start, stop)
    return (cx, cy, r) if ok else None


class Meeting(NamedTuple):
    """Where beams ``o + t·b`` meet the circle (c, r) (see
    :func:`agent.perception.features.circle_kernels.circle_model`)."""

    ocx: FloatArray  # c − o
    ocy: FloatArray
    big_b: FloatArray  # B = b·(c − o)
    half: FloatArray  # h = √(B² − |c − o|² + r²), 0 for a beam that misses
    t: FloatArray  # the meeting point's distance along the beam, B − h
    flen: FloatArray  # |o + t b − c|: r, or more for a beam that misses
    ux: FloatArray  # the outward normal there
    uy: FloatArray

    @staticmethod
    def of(
        ox: FloatArray,
        oy: FloatArray,
        bx: FloatArray,
        by: FloatArray,
        cx: float,
        cy: float,
        r: float,
    ) -> Meeting:
        ocx = cx - ox
        ocy = cy - oy
        big_b = bx * ocx + by * ocy
        half = np.sqrt(np.maximum(big_b * big_b - (ocx * ocx + ocy * ocy) + r * r, 0.0))
        t = big_b - half
        fx = t * bx - ocx  # meeting point − centre
        fy = t * by - ocy
        flen = np.maximum(np.hypot(fx, fy), 1e-12)
        return Meeting(ocx, ocy, big_b, half, t, flen, fx / flen, fy / flen)


class CircleFit(NamedTuple):
    q: FloatArray  # (cx, cy, r)
    cov: FloatArray  # (3, 3) over q
    chi2: float  # of the ranges and (when used) the intensities
    terms: int  # residuals in chi2
    params: int  # parameters fitted (3, or 4 with the log reflectivity)
    used: NDArray[np.bool_]  # the samples fitted
    second_z: float  # the second largest range residual over its σ


_NO_PAIRS = np.empty(0)


def circle_fit(
    rows: FloatArray,
    start: int,
    stop: int,
    guess: tuple[float, float, float],
    min_cos_incidence: float,
    max_radius: float = math.inf,
    intensity_min_cos: float = 0.5,
    pair_cov: FloatArray | None = None,
    iterations: int = 30,
    select_iterations: int = 3,
    hopeless_reduced_chi2: float = math.inf,
    blur_rad: float = 0.0,
) -> CircleFit | None:
    """Weighted circle fit along each sample's beam, with the intensities where known.

    Fits samples [start, stop) of the stacked ``rows`` (C-contiguous, see
    :mod:`agent.perception.features.rows`); the iterations run compiled
    (:func:`agent.perception.features.circle_kernels.circle_fit`). ``q`` = (cx, cy, r). Each
    sample's true position lies on its own beam (the scan angle is known to 0.1 mrad), so
    the model of sample i is where its beam meets the circle, and its residual is its offset
    along the surface normal there, ``e_i = u_i·(p_i − c) − r``, weighted by ``1/(u_iᵀ C_i
    u_i)``: the geometric distance along the radial direction, with the direction taken from
    the model rather than from the noisy point. The residual is then linear in the point's
    error (the range error scaled by cos(incidence)); a direction taken from the noisy point
    instead correlates weight with error near the silhouette, where the along-beam error is
    large and nearly tangential, and biased r = 0.1 m cylinders by −2σ in tests. For fixed
    normals the model is linear in (cx, cy, r): each Gauss-Newton step solves ``Aᵀ W A δ =
    Aᵀ W e``, A_i = (u_i, 1), and is halved until χ² falls.

    Where the samples carry intensity weights (``WINT``) the intensities join the fit
    (section 6.8: the surface's turning shows in them): each also contributes
    ``log(I·r²/(S cos θ)) − λ − log cos(viewing angle)`` with its own σ, λ the log
    reflectivity being a fourth parameter. Far away, where the range noise hides a small
    cylinder's curvature, this is what fixes its radius. Only beams meeting the circle
    within acos(``intensity_min_cos``) (60°) give intensities: nearer the silhouette the
    profile falls so steeply that the detection filter's and the footprint's smoothing
    over a fraction of a sample moves it by more than the model's few per cent.
    (:func:`agent.perception.features.circle_kernels.circle_model` has the model and its
    derivatives.)

    Beams meeting the circle at incidence beyond acos(``min_cos_incidence``) are left out:
    there the meeting point slides fast with the circle and the first-order model fails.
    The beams are chosen freely in the first ``select_iterations`` iterations, then only
    dropped (those that end up grazing or missing the circle: kept, their tiny across-beam
    variance would pin the circle's edge to them and fake precision), so the selection
    settles. Iterations stop when the selection is settled and a step is below 5 % of
    every parameter's σ or lowers χ² by less than ``circle_kernels.CREEP_CHI2``; with None
    once the radius grows past ``max_radius``, or once (the selection settled) even the minimum of
    the linearised model, ``χ² − δᵀ Aᵀ W e``, exceeds ``hopeless_reduced_chi2`` per degree
    of freedom.
    Covariance: the inverse normal matrix N⁻¹ (its (cx, cy, r) block); with ``pair_cov``
    (m−1,), the covariance of each sample's range error with the next's, the sandwich
    ``N⁻¹ (N + Σ_i c_i (a_i a_{i+1}ᵀ + a_{i+1} a_iᵀ)) N⁻¹`` over the range terms' weighted
    Jacobians.
    """
    ok, q, cov, chi2, terms, params, used, second_z = circle_kernels.circle_fit(
        rows, start, stop, *guess, min_cos_incidence, max_radius, intensity_min_cos,
        _NO_PAIRS if pair_cov is None else pair_cov, iterations, select_iterations,
        hopeless_reduced_chi2, blur_rad,
    )  # fmt: skip
    if not ok:
        return None
    return CircleFit(q, cov, chi2, terms, params, used, second_z)


def fit_circle(
    points_xy: ArrayLike,
    covariance: ArrayLike,
    origin_xy: ArrayLike,
    min_cos_incidence: float = 0.3,
) -> tuple[FloatArray, float, FloatArray, float, NDArray[np.bool_]] | None:
    """Weighted circle fit to points seen along beams from ``origin_xy`` (a convex surface).

    Parameters
    ----------
    points_xy : (m, 2) points, m. covariance : (m, 2, 2) their covariances, m².
    origin_xy : (m, 2) the centre of scanning each point's beam left from, m.
    min_cos_incidence : beams meeting the circle more obliquely are left out of the fit.

    Returns
    -------
    (center (2,), radius, cov (3, 3) over (cx, cy, r), χ², used (m,) bool) or None when the
    points fix no circle (fewer than 4 usable, collinear, diverging). Algebraic (Kåsa)
    start, then Gauss-Newton along the beams (see :func:`circle_fit`).
    """
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(covariance, dtype=np.float64).reshape(-1, 2, 2)
    o = np.asarray(origin_xy, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] < 4 or c.shape[0] != p.shape[0] or o.shape[0] != p.shape[0]:
        return None
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(c)) and np.all(np.isfinite(o))):
        return None
    rows = beam_rows(p, c, o)
    if rows is None:
        return None
    guess = kasa(rows, 0, rows.shape[1])
    if guess is None:
        return None
    out = circle_fit(rows, 0, rows.shape[1], guess, min_cos_incidence)
    if out is None:
        return None
    return out.q[:2].copy(), float(out.q[2]), out.cov, out.chi2, out.used
