"""The cylinder test: is a span of samples one cylinder, and which circle.

Section 6.8: a cylinder shows a distinct intensity peak at its centre. The intensity cue
comes first (a span that one plane explains, ranges and intensities, needs no test), then
an algebraic (Kåsa) circle and a weighted Gauss-Newton fit of the distances along the
radial direction, each sample's direction taken where its beam meets the circle
(:mod:`agent.perception.features.circles`); accepted by radius, convexity toward the
sensor, χ² consistent with the noise, no two samples beyond ``split_sigma``, and evidence
against a plane (a χ² gain over a line, or an intensity peak no plane can make). Beams
grazing the circle are left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agent.arrays import FloatArray
from agent.perception.features import cylinder_kernels
from agent.perception.features.circles import circle_fit, kasa
from agent.perception.features.lines import LineFits, Wtls, misfit, wtls
from agent.perception.features.rows import OX, OY, VARB, X, Y
from agent.perception.features.samples import Samples, per_span
from agent.perception.features.settings import FeatureSettings


@dataclass(frozen=True)
class Circle:
    """A cylinder found on samples [start, stop): its circle and the (cx, cy, r) covariance."""

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


# A circle fit is abandoned once the best its linearised model can reach misfits by this
# many times the reduced χ² a cylinder may have. Measured over 150 bench scenes: once their
# beams were chosen, the fits later accepted had linearised minima of at most 0.84 times
# it; the ones abandoned now (corners, two surfaces) sat at 10-300 times it for 20-50 steps.
_HOPELESS_FACTOR = 5.0


class Cylinders:
    """The cylinder test over a span of compressed samples."""

    def __init__(self, s: Samples, settings: FeatureSettings, lines: LineFits) -> None:
        self.s = s
        self.settings = settings
        self.lines = lines  # the same spans' line fits, shared with split-and-merge

    @per_span
    def test(self, start: int, stop: int) -> Circle | None:
        """Accept [start, stop) as a cylinder, or None (remembered per span)."""
        st = self.settings
        if stop - start < max(st.cylinder_min_points, 4):
            return None
        whole = self.lines.fit(start, stop)
        line = whole.fit if whole is not None else None
        if line is not None and self._plane(line):
            return None
        r_lo, r_hi = st.cylinder_radius_m

        def usable(g: tuple[float, float, float] | None) -> bool:
            return (
                g is not None
                and 0.5 * r_lo <= g[2] <= 2.0 * r_hi
                and self._convex(g[0], g[1], start, stop)
            )

        guess = kasa(self.s.rows, start, stop)
        if not usable(guess):
            guess = self._chord_guess(start, stop)
            if not usable(guess):
                return None
        assert guess is not None
        fit = circle_fit(
            self.s.rows, start, stop, guess, st.cylinder_min_cos_incidence, 2.0 * r_hi,
            st.intensity_min_cos, self.s.pair_cov[start : stop - 1],
            hopeless_reduced_chi2=_HOPELESS_FACTOR * st.cylinder_max_reduced_chi2,
            blur_rad=st.intensity_blur_rad,
        )  # fmt: skip
        if fit is None:
            return None
        cx, cy, r = fit.q.tolist()
        if not (r_lo <= r <= r_hi) or not self._convex(cx, cy, start, stop):
            return None
        used = fit.used
        if int(np.count_nonzero(used)) < st.cylinder_min_points:
            return None
        if fit.chi2 > st.cylinder_max_reduced_chi2 * (fit.terms - fit.params):
            return None
        if fit.cov[2, 2] > (st.cylinder_max_radius_sigma_ratio * r) ** 2:
            return None  # the samples do not fix a radius: no evidence of a cylinder
        if not self._unfitted_on_circle(cx, cy, r, start, stop, used):
            return None
        if fit.second_z > st.split_sigma:
            # Two samples off the circle by more than a line may be (see lines.misfit): at an end
            # of the run, the edge of a surface beside the cylinder that sits within the
            # reduced χ² (at 1.5 m, σ 8 mm: 9 of a wall's samples beside 98 of a
            # cylinder's biased it by 15 mm). One alone may be a spike; the χ² judges it.
            return None
        # Not a plane: a straight line through the same samples explains the ranges and
        # intensities clearly worse (the whole run's line when the circle used every sample).
        if used.all():
            flat = line
        else:
            rows = self.s.rows[:, start:stop]
            flat = wtls(np.ascontiguousarray(rows[:, used]), 0, int(np.count_nonzero(used)))
        if flat is not None:
            plane_chi2 = flat.chi2
            if fit.params == 4:
                plane_chi2 += cylinder_kernels.plane_intensity_misfit(
                    flat.rows, flat.start, flat.stop, flat.alpha, flat.rho
                )[2]
            if plane_chi2 - fit.chi2 < st.cylinder_min_chi2_gain:
                return None
        fitted = np.flatnonzero(used)
        first, last = start + int(fitted[0]), start + int(fitted[-1])
        return Circle(start, stop, cx, cy, r, fit.cov, fit.chi2, first, last + 1)

    def _plane(self, line: Wtls) -> bool:
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
        if misfit(line.stop - line.start, line.max_z, line.chi2, self.settings):
            return False
        count, max_z, chi2 = cylinder_kernels.plane_intensity_misfit(
            line.rows, line.start, line.stop, line.alpha, line.rho
        )
        return count >= 4 and not misfit(count, max_z, chi2, self.settings, params=1)

    def _unfitted_on_circle(
        self, cx: float, cy: float, r: float, start: int, stop: int, used: np.ndarray
    ) -> bool:
        """The samples of [start, stop) the fit left out lie on the circle all the same.

        The fit leaves out beams that graze the circle (beyond ``cylinder_min_cos_incidence``,
        2-3 samples at each silhouette) and beams that miss it. The first still lie on the
        cylinder; the second lie on another surface, and the span is not one cylinder, though
        the circle fitted to the rest may be good (a pillar sunk in a wall: the wall's
        samples either side left out, the span would be reported as one cylinder and the
        wall lost). A sample lies on the circle when its distance from the centre is within
        ``split_sigma`` of its along-beam σ of r (near the silhouette its error runs nearly
        along the surface, so this is generous there).
        """
        if used.all():
            return True
        rows = self.s.rows[:, start:stop][:, ~used]
        off = np.abs(np.hypot(rows[X] - cx, rows[Y] - cy) - r)
        return bool(np.all(off <= self.settings.split_sigma * np.sqrt(rows[VARB])))

    def _chord_guess(self, start: int, stop: int) -> tuple[float, float, float] | None:
        """A starting circle from the span's chord, for when the algebraic fit's is no
        cylinder: the radius half the chord from the first sample to the last, the centre
        behind the chord's midpoint by ``r²/D`` along the beam (``D`` its distance from the
        middle sample's origin: where a circle seen from ``D`` has its silhouette chord).

        The Kåsa fit is biased toward small, even concave, circles on a short arc in noise,
        the more so on a mover the sweep smears: a 0.25 m mover walking across at 0.7 m/s,
        its near surface 2.3 m away (σ about 5 cm a sample), was a cylinder in 25 of 40
        sweeps and a segment in the rest (``test_a_far_walking_mover_is_a_cylinder``: now
        40 of 40). The fit and every test after it are unchanged (the span need not be
        the whole silhouette: on a mover cut by the window's edge the start's radius was
        0.08-0.15 m and the fit's 0.22, the truth 0.23).
        """
        rows = self.s.rows
        x0, y0, x1, y1 = rows[X, start], rows[Y, start], rows[X, stop - 1], rows[Y, stop - 1]
        mid = (start + stop - 1) // 2
        mx, my = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        r = 0.5 * float(np.hypot(x1 - x0, y1 - y0))
        dx, dy = mx - rows[OX, mid], my - rows[OY, mid]
        d = float(np.hypot(dx, dy))
        if not (r > 0.0 and d > r):
            return None
        back = r * r / d
        return float(mx + back * dx / d), float(my + back * dy / d), r

    def _convex(self, cx: float, cy: float, start: int, stop: int) -> bool:
        """The centre lies farther from the sensor than most of the points (compiled:
        :func:`cylinder_kernels.convex`)."""
        return bool(cylinder_kernels.convex(self.s.rows, start, stop, cx, cy))
