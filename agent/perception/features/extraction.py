"""Features of one scan (:func:`extract_features`): its surfaces as segments and
cylinders, and the corners and occluding edges where they meet.

**Corners** where consecutive reported segments meet at ``corner_min_angle_deg`` or more
(inside one segment id, or across a segment boundary with no range jump: the filter also
breaks segments at the intensity step a corner makes). **Occluding edges** at segment
boundaries with a range jump, at the nearer surface's end, unless both sides lie on one
line (missing data on one surface).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from agent.arrays import FloatArray
from agent.perception.features import extraction_kernels
from agent.perception.features.cylinders import Circle
from agent.perception.features.lines import Line, wtls
from agent.perception.features.model import Feature, IndexArray, Side
from agent.perception.features.reflectivity import Reflectivities
from agent.perception.features.rows import BX, BY, OX, OY, RANGE, VARB
from agent.perception.features.samples import Samples, prepare_samples
from agent.perception.features.settings import FeatureSettings
from agent.perception.features.split_merge import bend_gain
from agent.perception.features.surfaces import Surface, Surfaces
from agent.sensor.params import nominal_sensor

# The sensor's baseline d (eq. 6.5; the chapter's 0.095 m).
NOMINAL_BASELINE_M = nominal_sensor().baseline_m


def _ro(a: NDArray[Any]) -> NDArray[Any]:
    a.flags.writeable = False
    return a


def _intersect(p: Line, q: Line) -> tuple[FloatArray, FloatArray] | None:
    """Intersection of two lines and its covariance from both lines' (α, ρ) covariances
    (see :func:`agent.perception.features.extraction_kernels.intersection`); None for
    (nearly) parallel lines."""
    ok, x, y, cov = extraction_kernels.intersection(
        *p.normal, p.rho, p.cov, *q.normal, q.rho, q.cov
    )
    return (np.array([x, y]), cov) if ok else None


class _Extractor:
    """Features at one scan's fitted surfaces and at the boundaries between them."""

    def __init__(self, s: Samples, settings: FeatureSettings) -> None:
        self.s = s
        self.st = settings
        self.reflectivity = Reflectivities(s, settings)

    def _samples(self, start: int, stop: int) -> IndexArray:
        return _ro(self.s.index[start:stop].copy())

    # -- features
    def segment(self, line: Line) -> Feature:
        ends = np.array(
            [
                line.project(*self.s.point(line.start)),
                line.project(*self.s.point(line.stop - 1)),
            ]
        )
        return Feature(
            kind="segment",
            params=_ro(np.array([line.alpha, line.rho])),
            covariance=_ro(line.reported_cov + self._bend_spread(line)),
            reflectivity=self.reflectivity.of(line),
            samples=self._samples(line.start, line.stop),
            endpoints=_ro(ends),
        )

    def _bend_spread(self, line: Line) -> FloatArray:
        """What a bend the splitter could not confirm adds to a segment's (α, ρ) covariance.

        A piece whose best two-line split lowers its χ² by more than
        ``bend_suspect_chi2_gain`` (though not by the ``bend_min_chi2_gain`` that splits
        it) may be two faces meeting at a shallow angle: its line then lies between them,
        off the face most of its samples hit by more than its first-order covariance
        says. Covered as a mixture: the two sides' lines (fitted apart, split where the
        gain is best) as the alternatives, each weighted by its share of the samples,
        ``Σ_i (n_i/n)·δ_i·δ_iᵀ`` with ``δ_i`` side i's (α, ρ) less the piece's. Zero below
        the threshold.
        """
        out = np.zeros((2, 2))
        fit = line.fit
        k, gain = bend_gain(line, self.st.min_segment_points)
        if k < 0 or gain <= self.st.bend_suspect_chi2_gain:
            return out
        for a, b in ((line.start, k), (k, line.stop)):
            side = wtls(fit.rows, a, b)
            if side is None:
                continue
            d_alpha = math.remainder(side.alpha - fit.alpha, 2.0 * math.pi)
            d_rho = side.rho - fit.rho
            if abs(d_alpha) > 0.5 * math.pi:  # the same line written the other way round
                d_alpha = math.remainder(d_alpha + math.pi, 2.0 * math.pi)
                d_rho = -side.rho - fit.rho
            d = np.array([d_alpha, d_rho])
            out += (b - a) / line.count * np.outer(d, d)
        return out

    def cylinder(self, circ: Circle) -> Feature:
        return Feature(
            kind="cylinder",
            params=_ro(np.array([circ.cx, circ.cy, circ.r])),
            covariance=_ro(circ.cov.copy()),
            reflectivity=self.reflectivity.of(circ),
            samples=self._samples(circ.start, circ.stop),
            center=_ro(np.array([circ.cx, circ.cy])),
            radius=circ.r,
        )

    def corner(self, p: Line, q: Line) -> Feature | None:
        st = self.st
        if not (p.reportable(st) and q.reportable(st)):
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
            reflectivity=self.reflectivity.of(p, q),
            samples=_ro(samples),
            point=_ro(pt.copy()),
        )

    def _on_line(self, k: int, line: Line) -> bool:
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

    def boundary(self, p: Surface, q: Surface) -> Feature | None:
        """Feature at the boundary between consecutive segment ids: an edge, a corner or none.

        ``p`` is the last item of one run, ``q`` the first of the next.
        """
        s = self.s
        st = self.st
        i, j = p.stop - 1, q.start  # the two samples either side of the boundary
        ri, rj = float(s.rows[RANGE, i]), float(s.rows[RANGE, j])
        var_i, var_j = float(s.rows[VARB, i]), float(s.rows[VARB, j])
        if abs(rj - ri) <= max(st.edge_min_jump_m, st.edge_jump_sigma * math.sqrt(var_i + var_j)):
            if isinstance(p, Line) and isinstance(q, Line):
                return self.corner(p, q)  # the filter broke at a corner's intensity step
            return None
        # Missing data on one surface: each side's end sample lies on the other's line.
        checks = [
            (k, ln)
            for k, ln in ((j, p), (i, q))
            if isinstance(ln, Line) and ln.count >= st.min_segment_points
        ]
        if checks and all(self._on_line(k, ln) for k, ln in checks):
            return None
        near, far, near_item = (i, j, p) if ri < rj else (j, i, q)
        if near_item.count < st.edge_min_points:
            return None
        return self.edge(near, far, near_item)

    def edge(self, near: int, far: int, item: Surface) -> Feature:
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
        ox, oy = float(s.rows[OX, near]), float(s.rows[OY, near])
        bnx, bny = float(s.rows[BX, near]), float(s.rows[BY, near])
        bfx, bfy = float(s.rows[BX, far]), float(s.rows[BY, far])
        r = math.hypot(px - ox, py - oy)
        # Angle between the two beams (they may be several dropped samples apart).
        dtheta = abs(math.atan2(bnx * bfy - bny * bfx, bnx * bfx + bny * bfy))
        gx, gy = ox + r * bfx - px, oy + r * bfy - py  # across the beam at the sample's range
        if isinstance(item, Line):
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
            reflectivity=self.reflectivity.of(item),
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
    items they join. See :class:`Feature` and :mod:`agent.perception.features.model` for the
    parameters and covariances. Samples with a nonzero flag, a negative segment id,
    non-finite geometry or a covariance that is not positive semi-definite are ignored.

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
    s = prepare_samples(
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
    surfaces = Surfaces(s, st)
    ex = _Extractor(s, st)
    features: list[Feature] = []
    previous_last: Surface | None = None
    for start, stop in s.runs:
        items = surfaces.of_run(start, stop)
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
                if isinstance(prev, Line) and isinstance(item, Line):
                    found = ex.corner(prev, item)
                    if found is not None:
                        features.append(found)
            if isinstance(item, Circle):
                features.append(ex.cylinder(item))
            elif item.reportable(st):
                features.append(ex.segment(item))
        previous_last = items[-1]
    return features
