"""Feature extraction: line segments, corners, occluding edges and cylinders from one scan.

Input is the filtering stage's output for one sweep (vehicle frame, REP-103): points with
their own 2×2 covariances (range σ along the beam from the sample's intensity, eq. 6.14-6.20,
and ``r·σ_θ`` across it), range-continuous segment ids, intensities and beam geometry.

Pipeline, per segment id (a range-continuous run of samples on one or more surfaces):

1. **Cylinder test** on the whole run (section 6.8: a cylinder shows a distinct intensity
   peak at its centre): the intensity cue first, then an algebraic (Kåsa) circle and a
   weighted Gauss-Newton fit of the distances along the radial direction, each sample's
   direction taken where its beam meets the circle; accepted by radius, convexity toward
   the sensor, χ² consistent with the noise, no two samples beyond ``split_sigma``, and
   evidence against a plane (a χ² gain over a line, or an intensity peak no plane can
   make). Beams grazing the circle are left out.
2. Otherwise **split and merge** into straight pieces. A piece is split when a point lies
   more than ``split_sigma`` of *its own* σ along the fitted normal from the piece's
   weighted line (so noisy far points do not over-split and precise near points do split);
   the split goes where two lines fit best (found for all split positions at once from
   prefix sums of weighted moments). Adjacent pieces are merged back when one line passes
   the same test, and the boundary between pieces is moved to where each point fits its
   own line best. Runs of consecutive short pieces (a curve the splitter chops up) get the
   cylinder test again, and so do circles with the next circle along the run (one cylinder
   beside another surface can come out in two).
3. Each piece is fitted by **weighted total least squares** in Hessian normal form
   ``x·cos α + y·sin α = ρ``, each point weighted by ``1/(nᵀ C_i n)``, its variance along
   the line normal ``n``; the normal depends on the fit, so the fit is iterated. The
   covariance of (α, ρ) is propagated to first order from every point's full 2×2 covariance
   (Arras & Siegwart's line-fit Jacobians, generalised to weighted moments and full C_i).
4. **Corners** where consecutive reported segments meet at ``corner_min_angle_deg`` or
   more (inside one segment id, or across a segment boundary with no range jump: the
   filter also breaks segments at the intensity step a corner makes). **Occluding edges**
   at segment boundaries with a range jump, at the nearer surface's end, unless both sides
   lie on one line (missing data on one surface). **Reflectivity** of every feature from
   intensity, range and incidence (eq. 6.10-6.11 inverted).

Feature conventions (all vehicle frame, metres and radians)
------------------------------------------------------------
=========  ==========================  ===================================  ===
kind       ``params``                  ``covariance``                       dof
=========  ==========================  ===================================  ===
segment    (α, ρ): ``x cos α + y sin   2×2 over (α [rad], ρ [m]); ρ ≥ 0,    2
           α = ρ``, the line's normal  α in (-π, π], the normal pointing
           angle and its distance      from the vehicle origin to the line
           from the vehicle origin
corner     (x, y) of the intersection  2×2 over (x, y), m², from both       2
                                       lines' (α, ρ) covariances
edge       (x, y) of the nearer        2×2 over (x, y), m²: the end         2
           surface's end, half-way     sample's covariance plus the gap's
           across the gap to the next  (uniform, width²/12, along the
           beam seen                   surface)
cylinder   (cx, cy, r)                 3×3 over (cx, cy, r), m²             3
=========  ==========================  ===================================  ===

Comparing a segment's α with a reference must wrap the difference to (-π, π]. When a line
passes close to the vehicle origin (ρ → 0) α becomes ill-defined; the covariance says so.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any, Literal, NamedTuple, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.arrays import FloatArray
from agent.perception import kernels
from agent.perception.kernels import (
    BX as _BX,
    BY as _BY,
    CXX as _CXX,
    CXY2 as _CXY2,
    CYY as _CYY,
    MIN_VARIANCE_M2 as _MIN_VARIANCE_M2,
    ONE as _ONE,
    OX as _OX,
    OY as _OY,
    RANGE as _RANGE,
    REFL as _REFL,
    ROWS as _ROWS,
    VARB as _VARB,
    VX as _VX,
    VY as _VY,
    WINT as _WINT,
    X as _X,
    Y as _Y,
)
from agent.sensor.params import nominal_sensor

__all__ = [
    "Feature",
    "FeatureKind",
    "FeatureSettings",
    "extract_features",
    "feature_to_dict",
    "fit_circle",
    "fit_line",
]

FeatureKind = Literal["segment", "corner", "edge", "cylinder"]
Side = Literal["left", "right"]
IndexArray = NDArray[np.intp]

# The sensor's baseline d (eq. 6.5; the chapter's 0.095 m).
NOMINAL_BASELINE_M = nominal_sensor().baseline_m


@dataclass(frozen=True)
class FeatureSettings:
    """Thresholds of the feature extractor.

    min_segment_points, min_segment_length_m : smallest reported line segment.
    split_sigma : a piece is split when a point lies further than this many of its own σ
        (along the line normal) from the piece's fitted line. 5σ: for a true line of 256
        points the chance of a false split is 256 × 5.7e-7 = 1.5e-4.
    split_chi2_ratio : a piece is also split when its χ² exceeds this many times its degrees
        of freedom (and its 5σ quantile): a curve misfits a line everywhere but nowhere by
        5σ. Twice the predicted variance: a σ misjudged by 20 % (the model's agreement with
        Table 1) does not split a plane.
    segment_max_along_noise_ratio : a line piece is reported only when its points' noise
        along the line (weighted variance) is at most this fraction of their true spread
        along it (the weighted scatter along the line less that noise). The first-order
        (α, ρ) covariance takes the spread as exact; noise in it adds a second-order α error
        whose variance is about this ratio times σ_α², and whose tails are a product of
        Gaussians'. 0.25: the spread at least twice the noise (σ). Reported segments that
        match a true wall have at most 0.25 in the perception bench (seed 0) and 0.42
        (seed 1, one of 305); the noise-dominated pieces the test removes (far, dark
        surfaces at grazing incidence, 10-30 samples along the beams) median 0.5.
    segment_max_curvature_ratio : ... and only when ρ's second-order error, ½ρσ_α² (the
        line turning about its centroid), is at most this many times the line's first-order
        σ across itself at its centroid. Its variance joins the reported covariance (see
        ``_Line.reported_cov``), but the error is χ²-shaped, not Gaussian; at 2 its σ is
        1.4 times the Gaussian part's. Beyond it the line's direction is so uncertain that
        (α, ρ) means little (σ_α of 0.2-1.6 rad on the pieces it removes).
    refine_window : samples either side of a boundary between pieces searched for the best
        boundary.
    corner_min_angle_deg : smallest angle between two lines reported as a corner.
    corner_max_offset_m : a corner's intersection must lie within this (plus 3σ) of both
        pieces' adjacent ends.
    edge_min_jump_m, edge_jump_sigma : a segment boundary is an occlusion when the range
        jumps by more than both this distance and this many σ of the difference.
    edge_min_points : fewest samples of the nearer surface behind an edge (the filter's
        shortest run).
    continuity_sigma : across a boundary, an end point within this many σ of the other
        side's line makes the two sides one surface (missing data, not an edge).
    cylinder_radius_m : accepted cylinder radii.
    cylinder_min_points : fewest samples a cylinder is fitted to.
    cylinder_max_reduced_chi2 : the circle's weighted χ² per degree of freedom must be below
        this (consistent with the predicted noise).
    cylinder_min_chi2_gain : the circle's χ² (ranges and intensities) must be below the
        plane's by at least this (one extra parameter; 16 is a 4σ improvement).
    range_bias_fraction : the calibrated ranges keep a bias that varies slowly over the
        scan and the range (the calibration's residual: at most 0.14 σ on its grid), common
        to the samples of one segment, so it does not average down with their number; the
        line covariances carry it as this fraction of each sample's σ, fully correlated.
    intensity_model_sigma : relative error of the intensity model (Lambertian, one
        reflectivity per surface, eq. 6.10-6.11) added in quadrature to each sample's
        ``I_n/I_s`` when intensities are fitted (see ``extract_features``). 2 %: at the
        true circles of simulated cylinders, with ``intensity_min_cos``, the log
        intensities' χ² per sample is then 0.01 within 0.8 m, 0.2 at 0.8-1.3 m and 1.2 at
        1.3-1.8 m (the smoothing over a fixed angle spans more of the profile far away).
    intensity_min_cos : intensities of beams meeting a circle more obliquely (beyond 60°)
        are not fitted (see ``_circle_fit``).
    cylinder_min_cos_incidence : samples meeting the fitted circle more obliquely (beyond
        73°) are left out of the fit: there the first-order model fails (tests: NEES 5 with
        them, 3 without, for r = 0.1 m at 1.2 m).
    reflectivity_min_cos_incidence : samples seen more obliquely are not used for
        reflectivity (the cosine divides the estimate and amplifies normal errors).
    reflectivity_min_samples : fewer usable samples give a NaN reflectivity.
    """

    min_segment_points: int = 5
    min_segment_length_m: float = 0.1
    split_sigma: float = 5.0
    split_chi2_ratio: float = 2.0
    segment_max_along_noise_ratio: float = 0.25
    segment_max_curvature_ratio: float = 2.0
    refine_window: int = 4
    corner_min_angle_deg: float = 30.0
    corner_max_offset_m: float = 0.05
    edge_min_jump_m: float = 0.05
    edge_jump_sigma: float = 5.0
    edge_min_points: int = 3
    continuity_sigma: float = 4.0
    cylinder_radius_m: tuple[float, float] = (0.03, 0.6)
    cylinder_min_points: int = 5
    cylinder_max_reduced_chi2: float = 3.0
    cylinder_min_chi2_gain: float = 16.0
    cylinder_min_cos_incidence: float = 0.3
    range_bias_fraction: float = 0.07
    intensity_model_sigma: float = 0.02
    intensity_min_cos: float = 0.5
    reflectivity_min_cos_incidence: float = 0.2
    reflectivity_min_samples: int = 3

    def __post_init__(self) -> None:
        counts = ("min_segment_points", "cylinder_min_points", "edge_min_points")
        if any(getattr(self, name) < 1 for name in counts) or self.refine_window < 0:
            raise ValueError("point counts must be at least 1 and refine_window at least 0")
        r_lo, r_hi = self.cylinder_radius_m
        if not 0.0 < r_lo < r_hi:
            raise ValueError(f"cylinder_radius_m must be 0 < low < high, got {r_lo}, {r_hi}")
        positive = ("split_sigma", "edge_jump_sigma", "continuity_sigma", "min_segment_length_m")
        if any(not getattr(self, name) > 0.0 for name in positive):
            raise ValueError(f"{', '.join(positive)} must be positive")


@dataclass(frozen=True, eq=False)
class Feature:
    """One feature of a scan, in the vehicle frame.

    Attributes
    ----------
    kind : "segment", "corner", "edge" or "cylinder".
    params : (dof,) float64; see the module docstring (segment (α, ρ); corner and edge
        (x, y); cylinder (cx, cy, r)).
    covariance : (dof, dof) float64 over ``params``; dof 2, or 3 for a cylinder.
    reflectivity : relative to the calibration target (off-white cardboard = 1); NaN when
        fewer than ``reflectivity_min_samples`` samples were usable.
    samples : indices into the scan's arrays of the samples the feature was fitted to (for a
        corner, both lines' samples; for an edge, the nearer surface's end sample; for a
        cylinder, all its run's samples, though the most oblique are left out of the fit).
    endpoints : (2, 2) for segments: the first and last sample projected on the line, in
        sample order.
    point : (2,) for corners and edges (the same as ``params``).
    center, radius : (2,) and m, for cylinders.
    nearer_side : for edges: "left" when the nearer (occluding) surface lies at the higher
        scan angle (counter-clockwise of the edge, to the left seen from the sensor),
        "right" when at the lower.
    """

    kind: FeatureKind
    params: FloatArray
    covariance: FloatArray
    reflectivity: float
    samples: IndexArray
    endpoints: FloatArray | None = None
    point: FloatArray | None = None
    center: FloatArray | None = None
    radius: float | None = None
    nearer_side: Side | None = None

    @property
    def dof(self) -> int:
        """Degrees of freedom of ``params`` (the χ² dof of a NEES test)."""
        return int(self.params.size)


_COVARIANCE_PARAMS: dict[str, str] = {
    "segment": "alpha_rad, rho_m (vehicle frame)",
    "corner": "x_m, y_m (vehicle frame)",
    "edge": "x_m, y_m (vehicle frame)",
    "cylinder": "cx_m, cy_m, r_m (vehicle frame)",
}


def feature_to_dict(
    feature: Feature, to_world: Callable[[FloatArray], FloatArray] | None = None
) -> dict[str, Any]:
    """A JSON-ready description of ``feature``.

    ``to_world`` maps (k, 2) vehicle-frame points to the world frame (None: identity). Only
    positions are mapped: ``covariance`` stays over the vehicle-frame parameters that
    ``covariance_params`` names. A NaN reflectivity becomes None (JSON has no NaN).
    """

    def world(points: FloatArray) -> list[list[float]]:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        mapped = pts if to_world is None else np.asarray(to_world(pts), dtype=np.float64)
        return [[float(v) for v in row] for row in mapped.reshape(-1, 2)]

    out: dict[str, Any] = {"kind": feature.kind}
    if feature.kind == "segment" and feature.endpoints is not None:
        out["endpoints_world"] = world(feature.endpoints)
    elif feature.kind in ("corner", "edge") and feature.point is not None:
        out["point_world"] = world(feature.point)[0]
        if feature.nearer_side is not None:
            out["nearer_side"] = feature.nearer_side
    elif feature.kind == "cylinder" and feature.center is not None:
        out["center_world"] = world(feature.center)[0]
        out["radius_m"] = float(feature.radius) if feature.radius is not None else None
    out["covariance"] = [[float(v) for v in row] for row in feature.covariance]
    out["covariance_params"] = _COVARIANCE_PARAMS[feature.kind]
    out["reflectivity"] = None if math.isnan(feature.reflectivity) else float(feature.reflectivity)
    return out


# ------------------------------------------------------------------------- the scan's samples
# (The rows of the stacked per-sample matrix, _ONE ... _WINT, are kernels'; see _Samples.)


@dataclass(frozen=True)
class _Samples:
    """The valid samples, compressed and grouped by segment id (scan order within each).

    ``rows`` stacks, per sample: 1, x, y, C_xx, 2·C_xy, C_yy, the beam's origin (x, y) and
    unit direction (x, y), the variance along the beam, range, intensity, and the
    reflectivity it implies at normal incidence (I_s·r²/(S·cos θ), eq. 6.10-6.11; NaN
    where the intensity is not positive), the unit vector from the point to the
    detector's viewpoint (a baseline to the head's left of the centre of scanning, eq. 6.5):
    the surface's Lambertian factor is the cosine between its normal and this direction,
    and the weight ``1/σ²`` of the log intensity (``σ² = (I_n/I_s)² + σ_model²``; 0 where
    the intensity is unknown or not positive).
    Weighted moments and projected variances of any run are then single matrix products
    over a slice of ``xy1`` and ``cov3``.
    """

    index: IndexArray  # (m,) index into the scan's arrays
    rows: FloatArray  # (_ROWS, m)
    theta: FloatArray  # (m,)
    runs: list[tuple[int, int]]  # [start, stop) of each segment id, in id order
    pair_cov: FloatArray  # (m − 1,) covariance of range errors of samples k and k + 1

    @property
    def xy1(self) -> FloatArray:
        return self.rows[_ONE : _Y + 1]

    @property
    def cov3(self) -> FloatArray:
        return self.rows[_CXX : _CYY + 1]

    def point(self, k: int) -> tuple[float, float]:
        return float(self.rows[_X, k]), float(self.rows[_Y, k])

    def cov2(self, k: int) -> FloatArray:
        cxx, cxy2, cyy = self.rows[_CXX : _CYY + 1, k].tolist()
        return np.array([[cxx, 0.5 * cxy2], [0.5 * cxy2, cyy]])

    def variance_along(self, k: int, c: float, s: float) -> float:
        """Sample k's variance along the unit vector (c, s)."""
        cxx, cxy2, cyy = self.rows[_CXX : _CYY + 1, k].tolist()
        return float(c * c * cxx + c * s * cxy2 + s * s * cyy)


def _prepare(
    points_xy: ArrayLike,
    covariance: ArrayLike,
    segment: ArrayLike,
    flag: ArrayLike,
    intensity_A: ArrayLike,
    range_m: ArrayLike,
    origin_xy: ArrayLike,
    beam_angle_rad: ArrayLike,
    signal_constant: float,
    baseline_m: float,
    noise_current_A: float | None,
    intensity_model_sigma: float,
    neighbour_correlation: float,
) -> _Samples | None:
    p = np.asarray(points_xy, dtype=np.float64)
    c = np.asarray(covariance, dtype=np.float64)
    seg = np.asarray(segment)
    fl = np.asarray(flag)
    inten = np.asarray(intensity_A, dtype=np.float64)
    rng = np.asarray(range_m, dtype=np.float64)
    org = np.asarray(origin_xy, dtype=np.float64)
    th = np.asarray(beam_angle_rad, dtype=np.float64)
    if seg.ndim != 1:
        raise ValueError(f"segment must be one-dimensional, got shape {seg.shape}")
    n = seg.shape[0]
    for name, got, want in (
        ("points_xy", p.shape, (n, 2)),
        ("covariance", c.shape, (n, 2, 2)),
        ("flag", fl.shape, (n,)),
        ("intensity_A", inten.shape, (n,)),
        ("range_m", rng.shape, (n,)),
        ("origin_xy", org.shape, (n, 2)),
        ("beam_angle_rad", th.shape, (n,)),
    ):
        if got != want:
            raise ValueError(f"{name} has shape {got}, expected {want} (n = {n} samples)")
    if n == 0:
        return None
    idx = np.flatnonzero((fl == 0) & (seg >= 0))
    if idx.size == 0:
        return None
    theta = np.take(th, idx)
    rows, good = kernels.sample_rows(
        np.take(p, idx, axis=0), np.take(c.reshape(n, 4), idx, axis=0),
        np.take(org, idx, axis=0), theta, np.take(rng, idx), np.take(inten, idx),
        signal_constant, baseline_m,
        math.nan if noise_current_A is None else noise_current_A, intensity_model_sigma,
    )  # fmt: skip
    if not good.all():
        keep = np.flatnonzero(good)
        if keep.size == 0:
            return None
        idx, rows, theta = idx[keep], rows[:, keep], theta[keep]
    seg_v = seg[idx]
    steps = np.diff(seg_v)
    if np.any(steps < 0):  # ids not in scan order: group them, keep scan order inside
        order = np.argsort(seg_v, kind="stable")
        idx, rows, theta = idx[order], rows[:, order], theta[order]
        steps = np.diff(seg[idx])
    cuts = (np.flatnonzero(steps) + 1).tolist()
    runs = list(itertools.pairwise([0, *cuts, idx.size]))
    # The spot at either end of a run straddles the run's edge (the footprint and the
    # detection filter span about a sample), so its intensity is not the surface's alone:
    # measured on planes, the run's end samples are the ones whose intensity misfits the
    # plane by 5-13 σ. Their intensities are not fitted (their ranges are).
    rows[_WINT, [0, *cuts]] = 0.0
    rows[_WINT, [c - 1 for c in cuts] + [idx.size - 1]] = 0.0
    # Range errors of neighbouring samples (consecutive in the scan) are correlated by the
    # detection filter: covariance ρ₁·σ_k·σ_{k+1} along the beams.
    sigma_b = np.sqrt(rows[_VARB])
    neighbours = np.diff(idx) == 1
    pair_cov = np.where(neighbours, neighbour_correlation * sigma_b[:-1] * sigma_b[1:], 0.0)
    rows = np.ascontiguousarray(rows)
    return _Samples(index=idx, rows=rows, theta=theta, runs=runs, pair_cov=pair_cov)


# -------------------------------------------------------------------------- weighted line fit
def _normal_variance(c: float, s: float, cov3: FloatArray) -> FloatArray:
    """Each point's variance along the unit vector (c, s): nᵀ C_i n, floored."""
    return np.maximum(np.array([c * c, c * s, s * s]) @ cov3, _MIN_VARIANCE_M2)


@dataclass(frozen=True)
class _Wtls:
    """A weighted TLS line through samples [start, stop) of ``rows`` (see :func:`_wtls`)."""

    alpha: float
    rho: float
    w: FloatArray  # (m,) weights 1/(nᵀ C n) used
    xm: float  # weighted centroid
    ym: float
    num: float  # N = −2 S_xy
    den: float  # D = S_yy − S_xx
    max_z: float  # largest |residual| / σ along the normal
    chi2: float  # Σ (residual / σ)²
    rows: FloatArray  # the stacked samples (see _Samples)
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
        beams (rows _BX, _BY, _VARB), so apply only when ``pair_cov`` is given.
        """
        with_beam = pair_cov is not None
        v_aa, v_ar, v_rr = kernels.line_covariance(
            self.rows, self.start, self.stop, self.w, self.alpha, self.xm, self.ym,
            self.num, self.den, pair_cov if pair_cov is not None else _NO_PAIRS,
            common_fraction, with_beam,
        )  # fmt: skip
        return np.array([[v_aa, v_ar], [v_ar, v_rr]])


_NO_PAIRS = np.empty(0)


def _wtls(rows: FloatArray, start: int, stop: int, iterations: int = 6) -> _Wtls | None:
    """Weighted total least squares line fit in Hessian normal form, or None.

    Fits samples [start, stop) of the stacked ``rows`` (C-contiguous, see _Samples); the
    iterations run compiled (:func:`agent.perception.kernels.wtls`). Minimises
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
    ok, a, rho, xm, ym, num, den, max_z, chi2, w = kernels.wtls(rows, start, stop, iterations)
    if not ok:
        return None
    return _Wtls(a, rho, w, xm, ym, num, den, max_z, chi2, rows, start, stop)


def _point_rows(points_xy: ArrayLike, covariance: ArrayLike) -> FloatArray:
    """Stacked rows (see :class:`_Samples`) for points (m, 2) and covariances (m, 2, 2)."""
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(covariance, dtype=np.float64).reshape(-1, 2, 2)
    if c.shape[0] != p.shape[0]:
        raise ValueError(f"{p.shape[0]} points but {c.shape[0]} covariances")
    rows = np.zeros((_ROWS, p.shape[0]))
    rows[_ONE] = 1.0
    rows[_X : _Y + 1] = p.T
    rows[_CXX] = c[:, 0, 0]
    rows[_CXY2] = c[:, 0, 1] + c[:, 1, 0]
    rows[_CYY] = c[:, 1, 1]
    return rows


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
    rows = _point_rows(points_xy, covariance)
    fit = _wtls(rows, 0, rows.shape[1])
    if fit is None:
        return None
    return fit.alpha, fit.rho, fit.covariance()


@dataclass(frozen=True)
class _Line:
    start: int  # [start, stop) into the compressed samples
    stop: int
    fit: _Wtls
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
        return self.fit.rows[_ONE : _Y + 1, self.start : self.stop]

    @property
    def cov3(self) -> FloatArray:
        """(3, count) rows C_xx, 2·C_xy, C_yy of the samples."""
        return self.fit.rows[_CXX : _CYY + 1, self.start : self.stop]

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
        return float(kernels.along_noise_ratio(fit.rows, self.start, self.stop, fit.w, fit.alpha))

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
        return 0.5 * self.fit.rho * v_aa / math.sqrt(max(across, _MIN_VARIANCE_M2))

    def project(self, x: float, y: float) -> tuple[float, float]:
        """The foot of the perpendicular from (x, y) on the line."""
        c, s = self.normal
        d = x * c + y * s - self.rho
        return x - d * c, y - d * s


def _misfit(
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


# ------------------------------------------------------------------------------ split & merge
_Owner = TypeVar("_Owner")
_Result = TypeVar("_Result")


def _per_span(
    method: Callable[[_Owner, int, int], _Result],
) -> Callable[[_Owner, int, int], _Result]:
    """Remember a method's result per span (start, stop) on its instance (one scan's)."""
    slot = f"_per_span_{method.__name__}"

    @functools.wraps(method)
    def remembered(self: _Owner, start: int, stop: int) -> _Result:
        memo: dict[tuple[int, int], _Result] = vars(self).setdefault(slot, {})
        key = (start, stop)
        if key not in memo:
            memo[key] = method(self, start, stop)
        return memo[key]

    return remembered


class _Lines:
    """Line fitting and split-and-merge over the compressed samples."""

    def __init__(self, s: _Samples, settings: FeatureSettings) -> None:
        self.s = s
        self.settings = settings

    @_per_span
    def fit(self, start: int, stop: int) -> _Line | None:
        """The weighted line through samples [start, stop) (remembered per span)."""
        fit = _wtls(self.s.rows, start, stop)
        if fit is None:
            return None
        pair_cov = self.s.pair_cov[start : stop - 1]
        return _Line(start, stop, fit, pair_cov, self.settings.range_bias_fraction)

    def _bad(self, line: _Line) -> bool:
        fit = line.fit
        return _misfit(line.count, fit.max_z, fit.chi2, self.settings)

    def _best_split(self, line: _Line) -> int:
        """Split position k (left [start, k), right [k, stop), ≥ 2 points each) of least cost.

        The cost of each side is its weighted TLS residual for weights fixed from the piece's
        normal: the smaller eigenvalue of its weighted scatter matrix, from prefix sums of
        weighted moments, so every split position is evaluated at once.
        """
        xy1 = line.xy1
        w = line.fit.w
        x = xy1[1] - xy1[1, 0]  # local origin: keeps the prefix sums well conditioned
        y = xy1[2] - xy1[2, 0]
        wx, wy = w * x, w * y
        cum = np.cumsum(np.stack([w, wx, wy, wx * x, wy * y, wx * y]), axis=1)
        left = cum[:, 1:-2]  # first k points, k = 2 .. count-2
        right = cum[:, -1:] - left

        def lam_min(mm: FloatArray) -> FloatArray:
            sw, sx, sy, sxx, syy, sxy = mm
            cxx = sxx - sx * sx / sw
            cyy = syy - sy * sy / sw
            cxy = sxy - sx * sy / sw
            return np.asarray(
                0.5 * (cxx + cyy) - np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy * cxy),
                dtype=np.float64,
            )

        cost = lam_min(left) + lam_min(right)
        return line.start + 2 + int(np.argmin(cost))

    def split_and_merge(
        self, start: int, stop: int, curve: Callable[[int, int], _Circle | None]
    ) -> list[_Item]:
        """Straight pieces of the run [start, stop), in sample order.

        A range that is not one line is first offered to ``curve`` (the cylinder test): a
        cylinder beside a wall on one range-continuous run comes out whole.
        """
        done: list[_Item] = []
        split: set[tuple[int, int]] = set()  # ranges already found not to be one line
        stack = [(start, stop)]
        while stack:
            a, b = stack.pop()
            line = self.fit(a, b)
            if line is None:
                continue  # fewer than 2 usable points: belongs to no line
            if self._bad(line):
                circle = curve(a, b)
                if circle is not None:
                    done.append(circle)
                    continue
                split.add((a, b))
                k = self._best_split(line)
                stack.append((k, b))
                stack.append((a, k))
            else:
                done.append(line)
        done.sort(key=lambda item: item.start)
        # Merge: adjacent pieces that one line explains (undoes splits at noise).
        i = 0
        while i + 1 < len(done):
            p, q = done[i], done[i + 1]
            if (
                isinstance(p, _Line)
                and isinstance(q, _Line)
                and p.stop == q.start
                and (p.start, q.stop) not in split
            ):
                merged = self.fit(p.start, q.stop)
                if merged is not None and not self._bad(merged):
                    done[i : i + 2] = [merged]
                    continue
            i += 1
        for i in range(len(done) - 1):
            p, q = done[i], done[i + 1]
            if isinstance(p, _Line) and isinstance(q, _Line):
                pair = self._refine_boundary(p, q)
                if pair is not None:
                    done[i], done[i + 1] = pair
        return done

    def _refine_boundary(self, p: _Line, q: _Line) -> tuple[_Line, _Line] | None:
        """Move the boundary between adjacent pieces to where each point fits its own line."""
        if p.stop != q.start or p.count < 3 or q.count < 3:
            return None
        s = self.s
        win = self.settings.refine_window
        lo = max(p.start + 2, p.stop - win)
        hi = min(q.stop - 2, q.start + win)
        if hi <= lo:
            return None
        xy1 = s.xy1[:, lo:hi]
        cov3 = s.cov3[:, lo:hi]

        def z2(line: _Line) -> FloatArray:
            c, sn = line.normal
            d = np.array([-line.rho, c, sn]) @ xy1
            return np.asarray(d * d / _normal_variance(c, sn, cov3))

        zp, zq = z2(p), z2(q)
        # cost(k) = Σ_{lo ≤ i < k} zp_i + Σ_{k ≤ i < hi} zq_i for k = lo .. hi
        cost = np.concatenate([[0.0], np.cumsum(zp)]) + np.concatenate(
            [np.cumsum(zq[::-1])[::-1], [0.0]]
        )
        k = lo + int(np.argmin(cost))
        if k == p.stop:
            return None
        p2, q2 = self.fit(p.start, k), self.fit(k, q.stop)
        if p2 is None or q2 is None:
            return None
        return p2, q2


# ------------------------------------------------------------------------- weighted circle fit
@dataclass(frozen=True)
class _Circle:
    start: int
    stop: int
    cx: float
    cy: float
    r: float
    cov: FloatArray  # (3, 3) over (cx, cy, r)
    chi2: float
    fit_start: int  # the first and one past the last sample the circle was fitted to (the
    fit_stop: int  # others, grazing or missing it, are in [start, stop) but not in the fit)

    @property
    def count(self) -> int:
        return self.stop - self.start


def _inv3(m: FloatArray) -> FloatArray | None:
    """Inverse of a 3×3 matrix by cofactors (faster than LAPACK at this size); None if singular."""
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    c00, c01, c02 = e * i - f * h, c * h - b * i, b * f - c * e
    det = a * c00 + d * c01 + g * c02
    if not (det != 0.0 and math.isfinite(det)):
        return None
    out = np.array(
        [
            [c00, c01, c02],
            [f * g - d * i, a * i - c * g, c * d - a * f],
            [d * h - e * g, b * g - a * h, a * e - b * d],
        ]
    )
    out /= det
    return out


def _kasa(x: FloatArray, y: FloatArray, w: FloatArray) -> tuple[float, float, float] | None:
    """Weighted algebraic circle fit (Kåsa 1976): minimise Σ w (x²+y² + D x + E y + F)²."""
    x0, y0 = float(x[0]), float(y[0])  # a local origin keeps the normal equations conditioned
    a = np.empty((3, x.size))
    a[0] = x - x0
    a[1] = y - y0
    a[2] = 1.0
    aw = a * w
    inv = _inv3(aw @ a.T)
    if inv is None:
        return None
    sol = (inv @ (aw @ -(a[0] * a[0] + a[1] * a[1]))).tolist()
    cu, cv = -0.5 * sol[0], -0.5 * sol[1]
    r2 = cu * cu + cv * cv - sol[2]
    if not (r2 > 0.0 and math.isfinite(r2)):
        return None
    return cu + x0, cv + y0, math.sqrt(r2)


class _Meeting(NamedTuple):
    """Where beams ``o + t·b`` meet the circle (c, r) (see :func:`kernels.circle_model`)."""

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
    ) -> _Meeting:
        ocx = cx - ox
        ocy = cy - oy
        big_b = bx * ocx + by * ocy
        half = np.sqrt(np.maximum(big_b * big_b - (ocx * ocx + ocy * ocy) + r * r, 0.0))
        t = big_b - half
        fx = t * bx - ocx  # meeting point − centre
        fy = t * by - ocy
        flen = np.maximum(np.hypot(fx, fy), 1e-12)
        return _Meeting(ocx, ocy, big_b, half, t, flen, fx / flen, fy / flen)


# A circle fit is abandoned once the best its linearised model can reach misfits by this
# many times the reduced χ² a cylinder may have. Measured over 150 bench scenes: once their
# beams were chosen, the fits later accepted had linearised minima of at most 0.84 times
# it; the ones abandoned now (corners, two surfaces) sat at 10-300 times it for 20-50 steps.
_HOPELESS_FACTOR = 5.0


class _CircleFit(NamedTuple):
    q: FloatArray  # (cx, cy, r)
    cov: FloatArray  # (3, 3) over q
    chi2: float  # of the ranges and (when used) the intensities
    terms: int  # residuals in chi2
    params: int  # parameters fitted (3, or 4 with the log reflectivity)
    used: NDArray[np.bool_]  # the samples fitted
    second_z: float  # the second largest range residual over its σ


def _circle_fit(
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
) -> _CircleFit | None:
    """Weighted circle fit along each sample's beam, with the intensities where known.

    Fits samples [start, stop) of the stacked ``rows`` (C-contiguous, see _Samples); the
    iterations run compiled (:func:`agent.perception.kernels.circle_fit`). ``q`` = (cx, cy, r). Each
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

    Where the samples carry intensity weights (``_WINT``) the intensities join the fit
    (section 6.8: the surface's turning shows in them): each also contributes
    ``log(I·r²/(S cos θ)) − λ − log cos(viewing angle)`` with its own σ, λ the log
    reflectivity being a fourth parameter. Far away, where the range noise hides a small
    cylinder's curvature, this is what fixes its radius. Only beams meeting the circle
    within acos(``intensity_min_cos``) (60°) give intensities: nearer the silhouette the
    profile falls so steeply that the detection filter's and the footprint's smoothing
    over a fraction of a sample moves it by more than the model's few per cent.
    (:func:`agent.perception.kernels.circle_model` has the model and its derivatives.)

    Beams meeting the circle at incidence beyond acos(``min_cos_incidence``) are left out:
    there the meeting point slides fast with the circle and the first-order model fails.
    The beams are chosen freely in the first ``select_iterations`` iterations, then only
    dropped (those that end up grazing or missing the circle: kept, their tiny across-beam
    variance would pin the circle's edge to them and fake precision), so the selection
    settles. Iterations stop when the selection is settled and a step is below 5 % of
    every parameter's σ or lowers χ² by less than ``kernels.CREEP_CHI2``; with None once the
    radius grows past ``max_radius``, or once (the selection settled) even the minimum of
    the linearised model, ``χ² − δᵀ Aᵀ W e``, exceeds ``hopeless_reduced_chi2`` per degree
    of freedom.
    Covariance: the inverse normal matrix N⁻¹ (its (cx, cy, r) block); with ``pair_cov``
    (m−1,), the covariance of each sample's range error with the next's, the sandwich
    ``N⁻¹ (N + Σ_i c_i (a_i a_{i+1}ᵀ + a_{i+1} a_iᵀ)) N⁻¹`` over the range terms' weighted
    Jacobians.
    """
    ok, q, cov, chi2, terms, params, used, second_z = kernels.circle_fit(
        rows, start, stop, *guess, min_cos_incidence, max_radius, intensity_min_cos,
        _NO_PAIRS if pair_cov is None else pair_cov, iterations, select_iterations,
        hopeless_reduced_chi2,
    )  # fmt: skip
    if not ok:
        return None
    return _CircleFit(q, cov, chi2, terms, params, used, second_z)


def _beam_rows(p: FloatArray, c: FloatArray, o: FloatArray) -> FloatArray | None:
    """Stacked rows (see :class:`_Samples`) for points (m, 2), covariances, origins."""
    rows = _point_rows(p, c)
    rows[_OX : _OY + 1] = o.T
    b = p - o
    length = np.hypot(b[:, 0], b[:, 1])
    if not np.all(length > 0.0):
        return None
    rows[_BX : _BY + 1] = (b / length[:, None]).T
    bx, by = rows[_BX], rows[_BY]
    rows[_VARB] = bx * (bx * rows[_CXX] + by * rows[_CXY2]) + by * by * rows[_CYY]
    rows[_VX], rows[_VY] = -bx, -by  # (no intensities here: the viewpoint is not used)
    rows[_WINT] = 0.0
    return rows


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
    start, then Gauss-Newton along the beams (see the module docstring).
    """
    p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(covariance, dtype=np.float64).reshape(-1, 2, 2)
    o = np.asarray(origin_xy, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] < 4 or c.shape[0] != p.shape[0] or o.shape[0] != p.shape[0]:
        return None
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(c)) and np.all(np.isfinite(o))):
        return None
    rows = _beam_rows(p, c, o)
    if rows is None:
        return None
    guess = _kasa(rows[_X], rows[_Y], 1.0 / np.maximum(rows[_CXX] + rows[_CYY], 1e-12))
    if guess is None:
        return None
    out = _circle_fit(rows, 0, rows.shape[1], guess, min_cos_incidence)
    if out is None:
        return None
    return out.q[:2].copy(), float(out.q[2]), out.cov, out.chi2, out.used


def _cos_view_line(rows: FloatArray, alpha: float) -> FloatArray:
    """Cosine of each sample's viewing angle on a plane of normal angle ``alpha``."""
    return np.asarray(
        np.abs(rows[_VX] * math.cos(alpha) + rows[_VY] * math.sin(alpha)), dtype=np.float64
    )


def _cos_view(rows: FloatArray, item: _Line | _Circle) -> FloatArray:
    """Cosine of each sample's viewing angle on the fitted surface (0 where it faces away).

    The surface normal is the line's, or the circle's where the sample's beam meets it.
    """
    if isinstance(item, _Line):
        return _cos_view_line(rows, item.alpha)
    meet = _Meeting.of(rows[_OX], rows[_OY], rows[_BX], rows[_BY], item.cx, item.cy, item.r)
    ux, uy = meet.ux, meet.uy
    return np.asarray(np.maximum(ux * rows[_VX] + uy * rows[_VY], 0.0), dtype=np.float64)


class _Cylinders:
    """The cylinder test over a span of compressed samples."""

    def __init__(self, s: _Samples, settings: FeatureSettings, lines: _Lines) -> None:
        self.s = s
        self.settings = settings
        self.lines = lines  # the same spans' line fits, shared with split-and-merge

    @_per_span
    def test(self, start: int, stop: int) -> _Circle | None:
        """Accept [start, stop) as a cylinder, or None (remembered per span)."""
        st = self.settings
        if stop - start < max(st.cylinder_min_points, 4):
            return None
        rows = self.s.rows[:, start:stop]
        whole = self.lines.fit(start, stop)
        line = whole.fit if whole is not None else None
        if line is not None and self._plane(line):
            return None
        r_lo, r_hi = st.cylinder_radius_m
        weights = 1.0 / np.maximum(rows[_CXX] + rows[_CYY], _MIN_VARIANCE_M2)
        guess = _kasa(rows[_X], rows[_Y], weights)
        if guess is None or not (0.5 * r_lo <= guess[2] <= 2.0 * r_hi):
            return None
        if not self._convex(guess[0], guess[1], rows):
            return None
        fit = _circle_fit(
            self.s.rows, start, stop, guess, st.cylinder_min_cos_incidence, 2.0 * r_hi,
            st.intensity_min_cos, self.s.pair_cov[start : stop - 1],
            hopeless_reduced_chi2=_HOPELESS_FACTOR * st.cylinder_max_reduced_chi2,
        )  # fmt: skip
        if fit is None:
            return None
        cx, cy, r = fit.q.tolist()
        if not (r_lo <= r <= r_hi) or not self._convex(cx, cy, rows):
            return None
        used = fit.used
        if int(np.count_nonzero(used)) < st.cylinder_min_points:
            return None
        if fit.chi2 > st.cylinder_max_reduced_chi2 * (fit.terms - fit.params):
            return None
        if fit.second_z > st.split_sigma:
            # Two samples off the circle by more than a line may be (see _misfit): at an end
            # of the run, the edge of a surface beside the cylinder that sits within the
            # reduced χ² (at 1.5 m, σ 8 mm: 9 of a wall's samples beside 98 of a
            # cylinder's biased it by 15 mm). One alone may be a spike; the χ² judges it.
            return None
        # Not a plane: a straight line through the same samples explains the ranges and
        # intensities clearly worse (the whole run's line when the circle used every sample).
        if used.all():
            flat = line
        else:
            flat = _wtls(np.ascontiguousarray(rows[:, used]), 0, int(np.count_nonzero(used)))
        if flat is not None:
            plane_chi2 = flat.chi2
            if fit.params == 4:
                plane_chi2 += kernels.plane_intensity_misfit(
                    flat.rows, flat.start, flat.stop, flat.alpha
                )[2]
            if plane_chi2 - fit.chi2 < st.cylinder_min_chi2_gain:
                return None
        fitted = np.flatnonzero(used)
        first, last = start + int(fitted[0]), start + int(fitted[-1])
        return _Circle(start, stop, cx, cy, r, fit.cov, fit.chi2, first, last + 1)

    def _plane(self, line: _Wtls) -> bool:
        """One plane explains the ranges and the intensities: no cylinder test needed.

        The ranges fit ``line`` as the splitter judges a line, and so do the intensities
        with the range, aperture and that line's viewing angles removed: one surface of one
        reflectivity, turning only as the beam does (cos 20° = 0.94 over the whole window).
        A cylinder hidden by range noise fails the second test (its intensity falls toward
        the silhouettes, the chapter's intensity peak, fig. 6.13b, also when seen in part);
        one seen close fails the first. The intensities' residuals are
        ``log(I·r²/(S cos θ)) − log cos(viewing angle) − λ`` over their σ, for the samples
        with a known intensity, λ their weighted mean (the plane's log reflectivity).
        """
        if _misfit(line.stop - line.start, line.max_z, line.chi2, self.settings):
            return False
        count, max_z, chi2 = kernels.plane_intensity_misfit(
            line.rows, line.start, line.stop, line.alpha
        )
        return count >= 4 and not _misfit(count, max_z, chi2, self.settings, params=1)

    @staticmethod
    def _convex(cx: float, cy: float, rows: FloatArray) -> bool:
        """The centre lies farther from the sensor than most of the points."""
        ox, oy = rows[_OX], rows[_OY]
        beyond = np.hypot(cx - ox, cy - oy) > rows[_RANGE]
        return 2 * int(np.count_nonzero(beyond)) > int(beyond.size)


# ---------------------------------------------------------------------------------- assembly
_Item = _Line | _Circle


def _ro(a: NDArray[Any]) -> NDArray[Any]:
    a.flags.writeable = False
    return a


def _median(values: FloatArray) -> float:
    m = values.size
    part = np.partition(values, [(m - 1) // 2, m // 2])
    return 0.5 * float(part[(m - 1) // 2] + part[m // 2])


def _intersect(p: _Line, q: _Line) -> tuple[FloatArray, FloatArray] | None:
    """Intersection of two lines and its covariance from both lines' (α, ρ) covariances.

    Solve A x = ρ with A = [[cos α₁, sin α₁], [cos α₂, sin α₂]]; ∂x/∂ρ_k = A⁻¹ e_k and
    ∂x/∂α_k = −A⁻¹ e_k (−sin α_k x + cos α_k y). The lines come from disjoint samples, so
    their errors are independent: Σ = J₁ Σ₁ J₁ᵀ + J₂ Σ₂ J₂ᵀ.
    """
    c1, s1 = p.normal
    c2, s2 = q.normal
    det = c1 * s2 - s1 * c2
    if abs(det) < 1e-9:
        return None
    # Columns of A⁻¹: k1 = (s2, −c2)/det, k2 = (−s1, c1)/det.
    k1x, k1y, k2x, k2y = s2 / det, -c2 / det, -s1 / det, c1 / det
    x = k1x * p.rho + k2x * q.rho
    y = k1y * p.rho + k2y * q.rho
    d1 = -s1 * x + c1 * y
    d2 = -s2 * x + c2 * y
    j1 = np.array([[-k1x * d1, k1x], [-k1y * d1, k1y]])  # ∂(x, y)/∂(α₁, ρ₁)
    j2 = np.array([[-k2x * d2, k2x], [-k2y * d2, k2y]])
    return np.array([x, y]), j1 @ p.cov @ j1.T + j2 @ q.cov @ j2.T


class _Extractor:
    def __init__(self, s: _Samples, settings: FeatureSettings) -> None:
        self.s = s
        self.st = settings
        self.lines = _Lines(s, settings)
        self.cylinders = _Cylinders(s, settings, self.lines)
        self._refl: dict[tuple[int, int], FloatArray] = {}

    # -- per run
    def run_items(self, start: int, stop: int) -> list[_Item]:
        """Cylinders and straight pieces of one run, in sample order."""
        cyl = self.cylinders.test(start, stop)
        if cyl is not None:
            return [cyl]
        pieces = self.lines.split_and_merge(start, stop, self.cylinders.test)
        # A curve the splitter chopped up: consecutive pieces none of which is a segment.
        items: list[_Item] = []
        i = 0
        while i < len(pieces):
            first = pieces[i]
            if isinstance(first, _Circle) or self.reportable(first):
                items.append(first)
                i += 1
                continue
            j = i + 1
            while j < len(pieces):
                nxt = pieces[j]
                if isinstance(nxt, _Circle) or self.reportable(nxt):
                    break
                if nxt.start != pieces[j - 1].stop:
                    break
                j += 1
            found = self._cylinder_over(first, pieces[j - 1]) if j - i >= 2 else None
            if found is not None:
                items.append(found)
            else:
                items.extend(pieces[i:j])
            i = j
        return self._joined_circles(items)

    def _joined_circles(self, items: list[_Item]) -> list[_Item]:
        """Circles that are one cylinder, joined with the short pieces between them.

        One cylinder beside a wall on one run fails the cylinder test whole when the wall's
        samples sit off the circle; split, it came out as two or three circles, maybe with
        pieces too short to be segments between them (2 % of the bench's cylinders).
        Reported twice, it would count its samples twice downstream. Each circle and the
        next one reached through such pieces are offered to the cylinder test together, as
        far as the circles were fitted: the samples at their ends that missed or grazed
        them may be the wall's. (A circle is not joined with the pieces beside it alone:
        at a wall, a few of its samples and the cylinder's silhouette then fitted a circle
        that passed the test yet was biased by 2 cm.)
        """
        out = list(items)
        k = 0
        while k < len(out):
            if not isinstance(out[k], _Circle):
                k += 1
                continue
            j = k + 1  # past the pieces too short to be segments that follow without a gap
            while (
                j < len(out)
                and out[j].start == out[j - 1].stop
                and isinstance(out[j], _Line)
                and not self.reportable(out[j])
            ):
                j += 1
            if j < len(out) and isinstance(out[j], _Circle) and out[j].start == out[j - 1].stop:
                joined = self._cylinder_over(out[k], out[j])
                if joined is not None:
                    out[k : j + 1] = [joined]
                    continue  # and try it with the next circle
            k += 1
        return out

    def _cylinder_over(self, first: _Item, last: _Item) -> _Circle | None:
        """The cylinder test from ``first`` to ``last`` (circles as far as they were fitted);
        the cylinder found spans both whole."""
        lo = first.fit_start if isinstance(first, _Circle) else first.start
        hi = last.fit_stop if isinstance(last, _Circle) else last.stop
        found = self.cylinders.test(lo, hi)
        return None if found is None else replace(found, start=first.start, stop=last.stop)

    def reportable(self, line: _Line) -> bool:
        """The piece is long enough and its (α, ρ) covariance describes its errors.

        Beyond the size limits, the first-order covariance must hold: the points' noise
        along the line small against their spread along it, and ρ's second-order error
        (the line turning about its centroid) not far beyond the first-order σ across the
        line (see ``FeatureSettings``). Pieces failing them are far, short runs of noisy
        samples or runs seen at grazing incidence, whose fitted line can miss the surface
        by many times its stated σ.
        """
        st = self.st
        if line.count < st.min_segment_points:
            return False
        # Separation of the end samples along the line.
        x0, y0 = self.s.point(line.start)
        x1, y1 = self.s.point(line.stop - 1)
        c, sn = line.normal
        if abs((y1 - y0) * c - (x1 - x0) * sn) < st.min_segment_length_m:
            return False
        return (
            line.along_noise_ratio <= st.segment_max_along_noise_ratio
            and line.curvature_ratio <= st.segment_max_curvature_ratio
        )

    def _reflectivities(self, item: _Item) -> FloatArray:
        """Usable per-sample reflectivities ``I_s·r² / (S·cos(viewing angle)·cos θ)``.

        Eq. 6.10-6.11 inverted. A Lambertian surface sends light toward the detector in
        proportion to the cosine of the *viewing* angle: between the fitted surface normal
        and the direction to the detector's viewpoint, a baseline (9.5 cm) to the side of
        the centre of scanning. (The beam's own incidence differs from it by up to d/r, 5° at 1 m:
        under 1 % on a plane seen nearly square-on, a quarter on a cylinder's flank at 70°.)
        """
        key = (item.start, item.stop)
        cached = self._refl.get(key)
        if cached is not None:
            return cached
        rows = self.s.rows[:, item.start : item.stop]
        cos_inc = _cos_view(rows, item)
        usable = cos_inc >= self.st.reflectivity_min_cos_incidence
        rho = rows[_REFL][usable] / cos_inc[usable]
        out = np.asarray(rho[np.isfinite(rho)], dtype=np.float64)
        self._refl[key] = out
        return out

    def _reflectivity(self, *items: _Item) -> float:
        values = [self._reflectivities(it) for it in items]
        joined = values[0] if len(values) == 1 else np.concatenate(values)
        if joined.size < self.st.reflectivity_min_samples:
            return math.nan
        return _median(joined)

    def _samples(self, start: int, stop: int) -> IndexArray:
        return _ro(self.s.index[start:stop].copy())

    # -- features
    def segment(self, line: _Line) -> Feature:
        ends = np.array(
            [
                line.project(*self.s.point(line.start)),
                line.project(*self.s.point(line.stop - 1)),
            ]
        )
        return Feature(
            kind="segment",
            params=_ro(np.array([line.alpha, line.rho])),
            covariance=_ro(line.reported_cov),
            reflectivity=self._reflectivity(line),
            samples=self._samples(line.start, line.stop),
            endpoints=_ro(ends),
        )

    def cylinder(self, circ: _Circle) -> Feature:
        return Feature(
            kind="cylinder",
            params=_ro(np.array([circ.cx, circ.cy, circ.r])),
            covariance=_ro(circ.cov.copy()),
            reflectivity=self._reflectivity(circ),
            samples=self._samples(circ.start, circ.stop),
            center=_ro(np.array([circ.cx, circ.cy])),
            radius=circ.r,
        )

    def corner(self, p: _Line, q: _Line) -> Feature | None:
        st = self.st
        if not (self.reportable(p) and self.reportable(q)):
            return None  # corners join reported segments (not the facets of a curve)
        angle = abs(math.remainder(p.alpha - q.alpha, math.pi))  # angle between the lines
        if angle < math.radians(st.corner_min_angle_deg):
            return None
        got = _intersect(p, q)
        if got is None:
            return None
        pt, cov = got
        s = self.s
        slack = st.corner_max_offset_m + 3.0 * math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0))
        for k in (p.stop - 1, q.start):
            x, y = s.point(k)
            if math.hypot(pt[0] - x, pt[1] - y) > slack:
                return None
        samples = np.concatenate([s.index[p.start : p.stop], s.index[q.start : q.stop]])
        return Feature(
            kind="corner",
            params=_ro(pt.copy()),
            covariance=_ro(cov),
            reflectivity=self._reflectivity(p, q),
            samples=_ro(samples),
            point=_ro(pt.copy()),
        )

    def _on_line(self, k: int, line: _Line) -> bool:
        """Sample k lies on ``line`` within ``continuity_sigma`` (point and line errors)."""
        c, sn = line.normal
        x, y = self.s.point(k)
        d = x * c + y * sn - line.rho
        # The line's variance at the point: ∂d/∂α = −x sin α + y cos α, ∂d/∂ρ = −1.
        ga = -x * sn + y * c
        cv = line.cov
        var_line = ga * ga * float(cv[0, 0]) - 2.0 * ga * float(cv[0, 1]) + float(cv[1, 1])
        var = var_line + self.s.variance_along(k, c, sn)
        return d * d <= self.st.continuity_sigma**2 * var

    def boundary(self, p: _Item, q: _Item) -> Feature | None:
        """Feature at the boundary between consecutive segment ids: an edge, a corner or none.

        ``p`` is the last item of one run, ``q`` the first of the next.
        """
        s = self.s
        st = self.st
        i, j = p.stop - 1, q.start  # the two samples either side of the boundary
        ri, rj = float(s.rows[_RANGE, i]), float(s.rows[_RANGE, j])
        var_i, var_j = float(s.rows[_VARB, i]), float(s.rows[_VARB, j])
        if abs(rj - ri) <= max(st.edge_min_jump_m, st.edge_jump_sigma * math.sqrt(var_i + var_j)):
            if isinstance(p, _Line) and isinstance(q, _Line):
                return self.corner(p, q)  # the filter broke at a corner's intensity step
            return None
        # Missing data on one surface: each side's end sample lies on the other's line.
        checks = [
            (k, ln)
            for k, ln in ((j, p), (i, q))
            if isinstance(ln, _Line) and ln.count >= st.min_segment_points
        ]
        if checks and all(self._on_line(k, ln) for k, ln in checks):
            return None
        near, far, near_item = (i, j, p) if ri < rj else (j, i, q)
        if near_item.count < st.edge_min_points:
            return None
        return self.edge(near, far, near_item)

    def edge(self, near: int, far: int, item: _Item) -> Feature:
        """Occluding edge at the nearer surface's end sample ``near``.

        The true edge lies somewhere between the beam of ``near`` and that of ``far`` (the
        next sample seen, on the farther surface), uniformly for beams that fall where they
        may. The point is placed half-way across that gap along the nearer surface, and its
        covariance is the end sample's plus the gap's uniform variance (width²/12) along the
        surface: without it the edge's error across the beam (up to r·Δθ, 2.7 mm per sample
        at 1 m) would dwarf the sample's own r·σ_θ.
        """
        s = self.s
        px, py = s.point(near)
        ox, oy = float(s.rows[_OX, near]), float(s.rows[_OY, near])
        bnx, bny = float(s.rows[_BX, near]), float(s.rows[_BY, near])
        bfx, bfy = float(s.rows[_BX, far]), float(s.rows[_BY, far])
        r = math.hypot(px - ox, py - oy)
        # Angle between the two beams (they may be several dropped samples apart).
        dtheta = abs(math.atan2(bnx * bfy - bny * bfx, bnx * bfx + bny * bfy))
        gx, gy = ox + r * bfx - px, oy + r * bfy - py  # across the beam at the sample's range
        if isinstance(item, _Line):
            c, sn = item.normal
            denom = bfx * c + bfy * sn
            if abs(denom) > 1e-9:
                t = (item.rho - (ox * c + oy * sn)) / denom  # the far beam meets the near line
                fx, fy = item.project(px, py)
                ax, ay = ox + t * bfx - fx, oy + t * bfy - fy
                # Use it unless the line runs nearly along the beam (then t means nothing).
                if t > 0.0 and math.hypot(ax, ay) < 5.0 * r * dtheta + 1e-3:
                    gx, gy = ax, ay
        pt = np.array([px + 0.5 * gx, py + 0.5 * gy])
        cov = s.cov2(near) + np.array([[gx * gx, gx * gy], [gx * gy, gy * gy]]) / 12.0
        side: Side = "left" if s.theta[near] > s.theta[far] else "right"
        return Feature(
            kind="edge",
            params=_ro(pt),
            covariance=_ro(cov),
            reflectivity=self._reflectivity(item),
            samples=_ro(np.array([s.index[near]], dtype=np.intp)),
            point=_ro(pt.copy()),
            nearer_side=side,
        )


def extract_features(
    points_xy: ArrayLike,
    covariance: ArrayLike,
    segment: ArrayLike,
    flag: ArrayLike,
    intensity_A: ArrayLike,
    range_m: ArrayLike,
    origin_xy: ArrayLike,
    beam_angle_rad: ArrayLike,
    signal_constant_Am2: float,
    *,
    baseline_m: float = NOMINAL_BASELINE_M,
    noise_current_A: float | None = None,
    neighbour_correlation: float = 0.0,
    settings: FeatureSettings | None = None,
) -> list[Feature]:
    """Segments, corners, occluding edges and cylinders of one filtered scan.

    Parameters
    ----------
    points_xy : (n, 2) sample positions, vehicle frame, m; NaN where dropped.
    covariance : (n, 2, 2) each point's covariance, m².
    segment : (n,) int, range-continuous run id (0, 1, ... in scan order), -1 where dropped.
    flag : (n,) uint8, 0 for a valid sample.
    intensity_A : (n,) signal current I_s, A.
    range_m : (n,) beam range from the centre of scanning, m.
    origin_xy : (n, 2) centre of scanning of each sample's beam, vehicle frame, m.
    beam_angle_rad : (n,) mirror scan angle θ, rad.
    signal_constant_Am2 : S of the calibration target (eq. 6.10), A·m².
    baseline_m : the detector's viewpoint lies this far to the head's left of the centre
        of scanning (eq. 6.5); it sets each sample's viewing angle for intensities.
    noise_current_A : the characterised ``I_n`` (eq. 6.14): with it, intensities join the
        cylinder fit and test, each log intensity with σ² = (I_n/I_s)² + σ_model²
        (``settings.intensity_model_sigma``); None fits ranges alone.
    neighbour_correlation : correlation of the range errors of samples next to each other
        in the scan (the detection filter's,
        :func:`agent.sensor.detection.sample_noise_correlation`:
        0.13 for the chapter's sensor); the fits' covariances account for it.
    settings : thresholds; the defaults when None.

    Returns
    -------
    Features in scan order: segments and cylinders, with corners and edges between the
    items they join. See :class:`Feature` and the module docstring for the parameters and
    covariances. Samples with a nonzero flag, a negative segment id, non-finite geometry or
    a covariance that is not positive semi-definite are ignored.

    Raises
    ------
    ValueError
        When the arrays' shapes disagree or the signal constant is not positive.
    """
    st = settings if settings is not None else FeatureSettings()
    if not (signal_constant_Am2 > 0.0 and math.isfinite(signal_constant_Am2)):
        raise ValueError(f"signal_constant_Am2 must be positive, got {signal_constant_Am2}")
    if noise_current_A is not None and not (
        noise_current_A > 0.0 and math.isfinite(noise_current_A)
    ):
        raise ValueError(f"noise_current_A must be positive, got {noise_current_A}")
    if not -1.0 < neighbour_correlation < 1.0:
        raise ValueError(f"neighbour_correlation must lie in (-1, 1), got {neighbour_correlation}")
    if not (baseline_m >= 0.0 and math.isfinite(baseline_m)):
        raise ValueError(f"baseline_m must be non-negative, got {baseline_m}")
    s = _prepare(
        points_xy,
        covariance,
        segment,
        flag,
        intensity_A,
        range_m,
        origin_xy,
        beam_angle_rad,
        float(signal_constant_Am2),
        float(baseline_m),
        noise_current_A,
        st.intensity_model_sigma,
        float(neighbour_correlation),
    )
    if s is None:
        return []
    ex = _Extractor(s, st)
    features: list[Feature] = []
    previous_last: _Item | None = None
    for start, stop in s.runs:
        items = ex.run_items(start, stop)
        if not items:
            previous_last = None
            continue
        if previous_last is not None:
            at_boundary = ex.boundary(previous_last, items[0])
            if at_boundary is not None:
                features.append(at_boundary)
        for k, item in enumerate(items):
            if k > 0:
                prev = items[k - 1]
                if isinstance(prev, _Line) and isinstance(item, _Line):
                    found = ex.corner(prev, item)
                    if found is not None:
                        features.append(found)
            if isinstance(item, _Circle):
                features.append(ex.cylinder(item))
            elif ex.reportable(item):
                features.append(ex.segment(item))
        previous_last = items[-1]
    return features
