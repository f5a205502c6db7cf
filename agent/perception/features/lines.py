"""Weighted line fits: the line through a span of samples, with its (α, ρ) covariance.

Each straight piece is fitted by **weighted total least squares** in Hessian normal form
``x·cos α + y·sin α = ρ``, each point weighted by ``1/(nᵀ C_i n)``, its variance along the
line normal ``n``; the normal depends on the fit, so the fit is iterated. The covariance of
(α, ρ) is propagated to first order from every point's full 2×2 covariance (Arras &
Siegwart's line-fit Jacobians, generalised to weighted moments and full C_i). A piece is
reported only where that covariance can hold (:meth:`Line.reportable`). The iterations run
compiled (:mod:`agent.perception.features.line_kernels`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from agent.arrays import FloatArray
from agent.perception.features import line_kernels
from agent.perception.features.rows import (
    BX,
    BY,
    CXX,
    CYY,
    MIN_VARIANCE_M2,
    ONE,
    RANGE,
    VARB,
    X,
    Y,
    point_rows,
)
from agent.perception.features.samples import Samples, per_span
from agent.perception.features.settings import FeatureSettings


@dataclass(frozen=True)
class Wtls:
    """A weighted TLS line through samples [start, stop) of ``rows`` (see :func:`wtls`)."""

    alpha: float
    rho: float
    w: FloatArray  # (m,) weights 1/(nᵀ C n) used
    xm: float  # weighted centroid
    ym: float
    num: float  # N = −2 S_xy
    den: float  # D = S_yy − S_xx
    max_z: float  # largest |residual| / σ along the normal
    chi2: float  # Σ (residual / σ)²
    rows: FloatArray  # the stacked samples (see samples.Samples)
    start: int
    stop: int

    def covariance(
        self, pair_cov: FloatArray | None = None, common_fraction: float = 0.0
    ) -> FloatArray:
        """2×2 covariance of (α, ρ), first-order from every point's full 2×2 covariance.

        Arras & Siegwart's propagation with weights held fixed: with N = −2 S_xy and
        D = S_yy − S_xx over weighted central moments,
        ∂α/∂x_i = w_i (N dx_i − D dy_i)/(N²+D²), ∂α/∂y_i = −w_i (D dx_i + N dy_i)/(N²+D²),
        ∂ρ/∂x_i = w_i cos α / Σw + (ȳ cos α − x̄ sin α) ∂α/∂x_i (likewise for y_i), and
        Σ_αρ = Σ_i J_i C_i J_iᵀ. Range errors of neighbouring samples are correlated (the
        detection filter spans them): with ``pair_cov`` (m−1,) the covariance of each
        sample's range error with the next's, ``Σ_i c_i (g_i g_{i+1}ᵀ + g_{i+1} g_iᵀ)`` is
        added, ``g_i = J_i b_i`` (b_i the beam's direction). A range error common to all the
        samples, ``common_fraction`` of each one's σ_i (the calibration's residual bias),
        adds the rank-one ``G Gᵀ``, ``G = common_fraction · Σ_i g_i σ_i``. Both need the
        beams (rows BX, BY, VARB), so apply only when ``pair_cov`` is given.
        """
        with_beam = pair_cov is not None
        v_aa, v_ar, v_rr = line_kernels.line_covariance(
            self.rows, self.start, self.stop, self.w, self.alpha, self.xm, self.ym,
            self.num, self.den, pair_cov if pair_cov is not None else _NO_PAIRS,
            common_fraction, with_beam,
        )  # fmt: skip
        return np.array([[v_aa, v_ar], [v_ar, v_rr]])


_NO_PAIRS = np.empty(0)


def wtls(rows: FloatArray, start: int, stop: int, iterations: int = 6) -> Wtls | None:
    """Weighted total least squares line fit in Hessian normal form, or None.

    Fits samples [start, stop) of the stacked ``rows`` (C-contiguous, see
    :mod:`agent.perception.features.rows`); the iterations run compiled
    (:func:`agent.perception.features.line_kernels.wtls`). Minimises
    Σ w_i (x_i cos α + y_i sin α − ρ)² with w_i = 1/(nᵀ C_i n), iterating because the
    weights depend on the normal (from the normal of the chord between the end points; two
    or three fits, stopping when the normal moves by under 1 % of σ_α). For fixed weights
    the solution is closed-form (Arras & Siegwart): ``α = ½·atan2(−2 S_xy, S_yy − S_xx)``
    over weighted central moments and ``ρ = x̄ cos α + ȳ sin α``; ρ ≥ 0 is kept by turning
    α by π.

    The moments are taken less what the points' own noise adds to them,
    ``Σ w_i C_i − Σ w_i² C_i / Σ w``: range noise lies along the beams, so on a surface
    seen obliquely it is correlated between the line's normal and its direction, and the
    fixed-weight fit turns the line toward the beams by ``Σ w_i tᵀC_i n / S_tt`` (``t``
    along the line). That is √(n·q) of σ_α (``q`` the points' noise along the line over
    their spread along it): 1.1 σ for 10 points 2 m away at 50° incidence with 3 cm range
    noise, in tests (the first-order covariance then held in one trial in three: NEES mean
    18). Less the noise, the fit is the maximum-likelihood line's estimating equation and
    that bias is gone (NEES mean 2.1 at 20 points, 60°, 4 cm). The (α, ρ) Jacobians are
    the same, with N and D the corrected moments'.
    """
    ok, a, rho, xm, ym, num, den, max_z, chi2, w = line_kernels.wtls(rows, start, stop, iterations)
    if not ok:
        return None
    return Wtls(a, rho, w, xm, ym, num, den, max_z, chi2, rows, start, stop)


def fit_line(points_xy: ArrayLike, covariance: ArrayLike) -> tuple[float, float, FloatArray] | None:
    """Weighted total-least-squares line through points with full 2×2 covariances.

    Parameters
    ----------
    points_xy : (m, 2) points, m. covariance : (m, 2, 2) their covariances, m².

    Returns
    -------
    (alpha, rho, cov) with ``x cos α + y sin α = ρ``, ρ ≥ 0, α in (-π, π], and ``cov`` the
    2×2 first-order covariance over (α [rad], ρ [m]); None for fewer than two distinct points.
    """
    rows = point_rows(points_xy, covariance)
    fit = wtls(rows, 0, rows.shape[1])
    if fit is None:
        return None
    return fit.alpha, fit.rho, fit.covariance()


@dataclass(frozen=True)
class Line:
    """A straight piece: the weighted line through samples [start, stop) of one scan's
    stacked samples (``fit.rows``)."""

    start: int  # [start, stop) into the compressed samples
    stop: int
    fit: Wtls
    pair_cov: FloatArray  # (count − 1,) covariance of neighbouring range errors
    common_fraction: float  # common range error, as a fraction of each sample's σ

    @property
    def alpha(self) -> float:
        return self.fit.alpha

    @property
    def rho(self) -> float:
        return self.fit.rho

    @property
    def count(self) -> int:
        return self.stop - self.start

    @property
    def normal(self) -> tuple[float, float]:
        return math.cos(self.fit.alpha), math.sin(self.fit.alpha)

    @property
    def xy1(self) -> FloatArray:
        """(3, count) rows 1, x, y of the samples."""
        return self.fit.rows[ONE : Y + 1, self.start : self.stop]

    @property
    def cov3(self) -> FloatArray:
        """(3, count) rows C_xx, 2·C_xy, C_yy of the samples."""
        return self.fit.rows[CXX : CYY + 1, self.start : self.stop]

    @cached_property
    def cov(self) -> FloatArray:
        """2×2 over (α, ρ); computed only for the pieces that need it."""
        return self.fit.covariance(self.pair_cov, self.common_fraction)

    @cached_property
    def along_noise_ratio(self) -> float:
        """The points' noise along the line over their true spread along it (scatters).

        ``Σ w_i tᵀC_i t`` (less the centroid's share) over the weighted scatter of the points
        along the line's direction ``t`` with that noise taken out; ∞ when the noise
        explains all of the scatter.
        """
        fit = self.fit
        return float(
            line_kernels.along_noise_ratio(fit.rows, self.start, self.stop, fit.w, fit.alpha)
        )

    @cached_property
    def reported_cov(self) -> FloatArray:
        """``cov`` with ρ's second-order error, ``−½ρ(δα² − σ_α²)``, added to σ_ρ².

        An error δα turns the line about its centroid: ρ then changes by the lever times
        δα (first order, in ``cov``) and by −½ρδα², whose variance is ½ρ²σ_α⁴. It matters
        for short, far segments, whose σ across the line at the centroid is small
        against ρσ_α².
        """
        out = self.cov.copy()
        out[1, 1] += 0.5 * (self.fit.rho * float(out[0, 0])) ** 2
        return out

    @cached_property
    def curvature_ratio(self) -> float:
        """ρ's second-order error, ½ρσ_α², over the line's σ across itself at its centroid."""
        cv = self.cov
        v_aa = float(cv[0, 0])
        across = float(cv[1, 1]) - float(cv[0, 1]) ** 2 / v_aa if v_aa > 0.0 else float(cv[1, 1])
        return 0.5 * self.fit.rho * v_aa / math.sqrt(max(across, MIN_VARIANCE_M2))

    def project(self, x: float, y: float) -> tuple[float, float]:
        """The foot of the perpendicular from (x, y) on the line."""
        c, s = self.normal
        d = x * c + y * s - self.rho
        return x - d * c, y - d * s

    @property
    def support_ratio(self) -> float:
        """The piece's range noise over its width across the beams, ``σ_b √(12/n) / W``.

        ``W`` is the arc the beams of its end samples span at its samples' mean range,
        ``σ_b`` the root mean square of their along-beam σ. It is the σ (rad) of the
        direction of a line fitted to ``n`` samples of a surface square-on to the beams,
        set by the beams the piece spans and not by its fitted direction: when it is
        large the fitted direction is the noise's (such a piece can come out turned 90°
        from its surface, and its first-order covariance does not describe it).
        """
        rows = self.fit.rows
        i, j = self.start, self.stop - 1
        n = self.stop - self.start
        turn = abs(float(rows[BX, i] * rows[BY, j] - rows[BY, i] * rows[BX, j]))
        mean_range = float(np.mean(rows[RANGE, i : j + 1]))
        width = turn * mean_range
        sigma = math.sqrt(float(np.mean(rows[VARB, i : j + 1])))
        if not width > 0.0:
            return math.inf
        return sigma * math.sqrt(12.0 / n) / width

    def reportable(self, settings: FeatureSettings) -> bool:
        """The piece is long enough and its (α, ρ) covariance describes its errors.

        Beyond the size limits, the first-order covariance must hold: the points' noise
        along the line small against their spread along it, and ρ's second-order error
        (the line turning about its centroid) not far beyond the first-order σ across the
        line (see ``FeatureSettings``). Pieces failing them are far, short runs of noisy
        samples or runs seen at grazing incidence, whose fitted line can miss the surface
        by many times its stated σ.
        """
        if self.count < settings.min_segment_points:
            return False
        # Separation of the end samples along the line.
        rows = self.fit.rows
        x0, y0 = float(rows[X, self.start]), float(rows[Y, self.start])
        x1, y1 = float(rows[X, self.stop - 1]), float(rows[Y, self.stop - 1])
        c, sn = self.normal
        if abs((y1 - y0) * c - (x1 - x0) * sn) < settings.min_segment_length_m:
            return False
        if self.support_ratio > settings.segment_max_support_ratio:
            return False  # too few beams across too much range noise: see FeatureSettings
        return (
            self.along_noise_ratio <= settings.segment_max_along_noise_ratio
            and self.curvature_ratio <= settings.segment_max_curvature_ratio
        )


def misfit(
    count: int, max_abs_z: float, chi2: float, settings: FeatureSettings, params: int = 2
) -> bool:
    """A fit of ``params`` parameters to ``count`` residuals over σ, the largest
    ``max_abs_z`` and their sum of squares ``chi2``, shows it is not one line (or surface).

    A point beyond ``split_sigma`` of its σ, or a χ² far too large: a gentle curve stays
    within 5σ everywhere yet misfits everywhere, so also when χ² exceeds both
    ``split_chi2_ratio`` × dof and its own upper 5σ point (Wilson-Hilferty's approximation
    of the χ² quantile). Fewer than four residuals never misfit.
    """
    if count < 4:
        return False
    if max_abs_z > settings.split_sigma:
        return True
    dof = count - params
    k = 2.0 / (9.0 * dof)
    upper = dof * (1.0 - k + settings.split_sigma * math.sqrt(k)) ** 3
    return chi2 > max(settings.split_chi2_ratio * dof, upper)


class LineFits:
    """The weighted lines through spans of one scan's samples, each span fitted once."""

    def __init__(self, s: Samples, settings: FeatureSettings) -> None:
        self.s = s
        self.settings = settings

    @per_span
    def fit(self, start: int, stop: int) -> Line | None:
        """The weighted line through samples [start, stop) (remembered per span)."""
        fit = wtls(self.s.rows, start, stop)
        if fit is None:
            return None
        pair_cov = self.s.pair_cov[start : stop - 1]
        return Line(start, stop, fit, pair_cov, self.settings.range_bias_fraction)
