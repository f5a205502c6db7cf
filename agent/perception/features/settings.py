"""The feature extractor's thresholds, each with the reason for its value."""

from __future__ import annotations

from dataclasses import dataclass


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
    bend_min_chi2_gain : a piece is also split when the best split into two lines lowers
        its χ² by more than this (a shallow bend, see ``SplitMerge._bent``). Not a
        textbook χ² point: the statistic is the largest over all split positions, and the
        range errors are correlated between neighbours and carry the calibration's slow
        residual, so it runs larger than χ²(2) on a true plane. Measured on the perception
        bench (seed 0, 300 scenes) before the test existed: over the 454 line pieces lying
        wholly on one straight face it had median 9, 99th percentile 31, largest 39; over
        the 11 single lines fitted across 10-20° bends, 20-210 (8 of them above 50). 50:
        above every straight face there, and no false split in 400 synthetic scans of a
        wall from 0.6 to 2.4 m at up to 79° incidence (30 split 2 of them); on the bench
        (seed 0, 300 scenes) lines across a bend fell from 8 of 50 bends to 2. 45 since:
        over 3000 bench scenes (500 bends), 50 left 29 lines across a bend (5.8 % of the
        bends; 25 of them uncovered, NEES 6-170, their gains 10-50 at χ² per degree of
        freedom 1.0-1.3) and the segments' NEES mean at 12.2 (a few such lines in the
        thousands). At 50 / 45 / 40 / 30: lines across 5.8 / **5.0** / 4.2 / 3.8 % of the
        bends, NEES mean 12.2 / **2.82** / 2.78 / 2.82, the general scenes' straight faces
        never bridged and their detection 95.5 % throughout, false features 0.018 /
        0.016 / 0.016 / 0.016 a scan; but from 40 down one of the 400 oblique walls of
        ``test_lines`` (seed 293, 0.6-2.4 m, up to 79°) splits: a straight face's gain
        reaches 40-45 there.
    bend_suspect_chi2_gain : a reported segment whose best two-line split gains more than
        this (but not ``bend_min_chi2_gain``) may be two faces at a shallow angle that its
        residuals cannot tell from a straight face's correlated noise; its covariance gets
        the two sides' spread (``extraction._Extractor._bend_spread``), so that it covers
        either face. Measured on the perception bench (3000 scenes, seed 0), off / 30 /
        **20** / 15: lines across a bend and uncovered 3.0 / 1.4 / **0.6** / 0.6 % of the
        bends (of 5.0 % across), segments' NEES mean 2.82 / 2.56 / **2.06** / 1.86, their
        tails above the χ² 95 % point 7.3 / 6.7 / **6.0** / 5.0 % and below the 5 % point
        5.0 / 5.6 / **7.6** / 11.3 % (straight faces reach such gains too, and their
        covariance grows with it), grazing segments > 5° off and uncovered 0.2 / 0 / 0 / 0 %.
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
        ``lines.Line.reported_cov``), but the error is χ²-shaped, not Gaussian; at 2 its σ is
        1.4 times the Gaussian part's. Beyond it the line's direction is so uncertain that
        (α, ρ) means little (σ_α of 0.2-1.6 rad on the pieces it removes).
    segment_max_support_ratio : ... and only when its beams span enough across its range
        noise: ``σ_b √(12/n) / W`` at most this (rad; see ``lines.Line.support_ratio``),
        the σ of the direction of a line through n samples over a width W across the
        beams, with along-beam σ_b. 0.5 (29°): beyond it the fitted direction is the
        noise's. On the perception bench (seed 0, 400 general scenes) 5-10-sample pieces at
        2.1-2.4 m, turned 75-90° from their wall, passed the other checks and made the
        segment NEES mean 8 456; with the check it is 2.2, at the cost of 0.4 % of the
        segments detected (96.4 → 96.0 %; 0.3 would cost 0.8 %).
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
        ``I_n/I_s`` when intensities are fitted (see ``extract_features``). 0.3 %: at the
        true circles of the perception bench's fence posts (seed 0, 200 scenes, 32 000
        samples), with the intensities reduced by the model's range (not the measured one,
        see ``circle_kernels.circle_model``) and the smoothing corrected
        (``intensity_blur_rad``), the log intensities scatter by 0.06-0.2 % square-on and
        0.4-0.6 % beyond 45° incidence. It was 2 %, set from the scatter about the
        measured range, which carried the range noise (2σ_r/r: 0.2 % at 0.7 m, 1.6-2.8 %
        at 1.4-2 m): near the sensor it inflated the cylinders' covariances threefold (17 %
        of fence posts' NEES below the χ² 5 % point at 1-1.4 m), far away it was too small.
        With 0.3 % the fence posts' errors over their σ have spread 0.98 along the beam,
        0.93 across it and 0.84 in r, alike at every range (0.3-1.1 before). 0.2 % since:
        over every class of ``bench perception`` (3000 scenes, seed 0, 3006 cylinders
        associated by shared samples), 0.3 % left the cylinders' NEES conservative (mean
        2.59 for 3 dof, 10.5 % below the χ² 5 % point and 4.8 % above the 95 % point);
        at 0.15 / 0.2 / 0.25 / 0.3 / 0.5 % the mean was 3.80 / **3.19** / 2.86 / 2.59 / 2.07,
        the tails above 11.3 / **8.4** / 6.2 / 4.8 / 2.3 % and below 8.4 / **9.2** / 9.9 /
        10.5 / 13.2 %, the radius's RMS error 0.15 / 0.16 / 0.17 / 0.18 / 0.25 mm; nothing
        else the bench measures moved. (The scatter above grows with incidence, so one
        constant is a compromise: a cylinder's across-beam and radius errors are 0.70-0.75
        of their σ at 2-2.6 m and 1.2-1.4 below 1 m.)
    intensity_blur_rad : σ of the angle of the beam's sweep over which the laser footprint
        and the detection filter average each intensity. Across a cylinder the averaged
        profile falls short of the Lambertian one at the beam's centre, by a few 0.1 %
        toward the silhouettes far away, which biased radii by −0.6σ once the intensities
        were weighted at their true σ; the circle model corrects for it (see
        ``circle_kernels.circle_model``). 1.45 mrad: the least-squares fit of the
        correction to the log intensities at the bench's true circles (above); from the
        sensor's parameters, the 1 kHz Bessel filter's impulse response (σ about 0.13 ms
        at the mirror's 7 rad/s, 0.9 mrad) and the footprint (0.5-0.8 mrad) give about
        1.1 mrad, the rest being the model's second-order truncation near the
        silhouettes.
    intensity_min_cos : intensities of beams meeting a circle more obliquely (beyond 60°)
        are not fitted (see ``circles.circle_fit``).
    cylinder_max_radius_sigma_ratio : a circle whose radius σ exceeds this fraction of
        the radius is not reported as a cylinder (its samples do not fix a radius: a short,
        far piece of a wall that a circle happens to fit better than a line). True posts
        on the bench have σ_r/r of 0.2 % median, 6 % at the 99th percentile (3 of 1 311
        above 0.25); the circles it refused there had 1.6-5.5.
    cylinder_min_cos_incidence : samples meeting the fitted circle more obliquely (beyond
        73°) are left out of the fit: there the first-order model fails (tests: NEES 5 with
        them, 3 without, for r = 0.1 m at 1.2 m).
    reflectivity_min_cos_incidence : samples seen more obliquely are not used for
        reflectivity (the cosine divides the estimate and amplifies normal errors).
    reflectivity_min_samples : fewer usable samples give a NaN reflectivity.
    depth_of_field_m : the filter's depth of field (``FilterSettings.depth_of_field_m``,
        0.4-2.5 m): it drops every sample whose *measured* range falls outside it, so the
        samples kept of a surface within a few σ of a limit are censored, their errors
        biased toward the inside (at the far limit, where σ is 5-6 cm, by up to 0.8σ).
    censor_margin_sigma : a line piece leaves out the samples at its ends whose range
        *predicted by its own line* (not the measured one, which the censoring selected)
        lies within this many of their σ of a limit, and is fitted again on the rest
        (:meth:`agent.perception.features.surfaces.Surfaces.uncensored`). 2: the censoring
        then biases a kept sample by at most 0.055σ. Measured with the physical simulator
        (150 scans a wall, the head at rest; before → after): a wall square-on at 2.35 m,
        segment NEES mean 5.7 → 3.3 (ρ biased −1.1 → −0.9 cm against a stated σ of 6 mm:
        the calibration's own bias there, about −0.1σ a sample, remains), one from 2.2 to
        2.9 m 4.7 → 2.5, one from 1.9 to 2.7 m 5.0 → 2.5 (its α scattered 0.069 rad
        against a stated 0.012, now 0.014 against 0.013); in ``bench tracking --policy
        forward`` (scenes 0-2, 22, 32, 51, 75 and 76) 68 % of the segment features had
        an end at 2.3-2.6 m, and their NEES mean over all was 5.8 (22 % above the χ² 95 %
        point) → 2.7 (9 %). The synthetic scans of
        ``tests/unit/perception/features/test_censoring.py``: 3.7 → 1.8 and 4.8 → 2.0.
    """

    min_segment_points: int = 5
    min_segment_length_m: float = 0.1
    split_sigma: float = 5.0
    split_chi2_ratio: float = 2.0
    bend_min_chi2_gain: float = 45.0
    bend_suspect_chi2_gain: float = 20.0
    segment_max_along_noise_ratio: float = 0.25
    segment_max_curvature_ratio: float = 2.0
    segment_max_support_ratio: float = 0.5
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
    intensity_model_sigma: float = 0.002
    intensity_min_cos: float = 0.5
    cylinder_max_radius_sigma_ratio: float = 0.25
    intensity_blur_rad: float = 1.45e-3
    reflectivity_min_cos_incidence: float = 0.2
    reflectivity_min_samples: int = 3
    depth_of_field_m: tuple[float, float] = (0.4, 2.5)
    censor_margin_sigma: float = 2.0

    def __post_init__(self) -> None:
        counts = ("min_segment_points", "cylinder_min_points", "edge_min_points")
        if any(getattr(self, name) < 1 for name in counts) or self.refine_window < 0:
            raise ValueError("point counts must be at least 1 and refine_window at least 0")
        r_lo, r_hi = self.cylinder_radius_m
        if not 0.0 < r_lo < r_hi:
            raise ValueError(f"cylinder_radius_m must be 0 < low < high, got {r_lo}, {r_hi}")
        positive = (
            "split_sigma",
            "edge_jump_sigma",
            "continuity_sigma",
            "min_segment_length_m",
            "bend_min_chi2_gain",
            "bend_suspect_chi2_gain",
            "segment_max_support_ratio",
            "cylinder_max_radius_sigma_ratio",
        )
        if any(not getattr(self, name) > 0.0 for name in positive):
            raise ValueError(f"{', '.join(positive)} must be positive")
        near, far = self.depth_of_field_m
        if not 0.0 <= near < far:
            raise ValueError(f"depth_of_field_m must be 0 <= near < far, got {near}, {far}")
        if not self.censor_margin_sigma >= 0.0:
            raise ValueError(
                f"censor_margin_sigma must be non-negative, got {self.censor_margin_sigma}"
            )
        if not self.intensity_blur_rad >= 0.0:
            raise ValueError(
                f"intensity_blur_rad must be non-negative, got {self.intensity_blur_rad}"
            )
