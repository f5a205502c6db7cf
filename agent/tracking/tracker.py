"""The tracker: one Kalman filter per feature in ``odom``, updated scan by scan.

Per scan (:meth:`Tracker.update`), given the scan's features in ``base_link``, the filtered
scan's samples and the odometry pose and covariance at the scan's reference time:

1. **Predict** every track to the scan's time, with the odometry's drift as process noise
   (:mod:`agent.tracking.geometry`) and, for cylinders, their motion model.
2. **Transform** the features into ``odom`` with the pose, their covariances with them.
3. **Gate** each feature against each track of its kind by Mahalanobis distance at the
   χ² quantile ``gate_probability`` for 2 degrees of freedom (segments: α, ρ in
   ``base_link``, near the lines, and overlapping extents; corners: x, y; cylinders: the
   centre), and **assign** globally per kind
   (``scipy.optimize.linear_sum_assignment``) on the cost ``d² + ln det S`` (the negative log
   likelihood, so a tight track is preferred over a loose one at equal distance).
4. **Update** the assigned tracks. A feature left unassigned inside another track's gate
   (a wall seen in two pieces, a corner reported twice) starts no track; a segment piece
   still extends that track's extent. The other unassigned features start tentative tracks.
5. **Book-keep by expected visibility** (:mod:`agent.tracking.visibility`): a track that the
   scan should have seen and did not is missed; one out of the window, out of range or
   occluded coasts. Confirmation is M of N over scans that could see the track; a confirmed
   static track is deleted after ``delete_misses`` consecutive expected-visible misses only
   (never for being out of view); a moving one also after ``max_coast_moving_s`` unseen;
   a tentative one when it can no longer reach M of N, or after ``tentative_timeout_s``.

**Kinds.** Segments: state (α, ρ) of the line in ``odom``; the extent (two end points) is
bookkeeping beside it, grown where a feature reaches further, and set (grown or shrunk)
where the scan saw that end as a real end (:func:`agent.tracking.visibility.segment_ends_seen`).
Corners: a static point. Cylinders: an interacting multiple model (IMM) of a static and a
constant-velocity model over (x, y, vx, vy), with the radius as a separate static estimate;
its CV model's probability is the track's ``moving_probability``. The IMM's CV alternative
cannot be predicted over the tens of seconds a static pillar may stay out of view (its
white-acceleration noise alone spreads it over metres, and even at a few per cent it would
swamp the combined covariance): a cylinder still taken as static when last updated and
unseen for longer than ``hold_static_after_s`` (confirmed) or than a mover may coast
(``max_coast_moving_s``, tentative) keeps its static model only, the CV model re-armed from
it at each scan with a new track's velocity prior. Held, it grows by the motion its watch
could not rule out (``static_resolution_m``): a walker glimpsed briefly is not kept, tight
and static, where it was.

**Timing.** A scan takes up to 0.1 s and a mover moves up to 8 cm meanwhile, so each
cylinder feature is dated by its own samples (:func:`feature_times`) and gated and updated
as a measurement of the position that long before the stamp (``H = [I, −τ·I]``, without
the white-acceleration noise of those last ``τ`` s: exactly an update at the feature's
time), its centre's error from the smear of a fit over samples of different times added
to ``R``. **Honest covariances.** The odometry's drift is added relative to each point
track's last update (:meth:`Tracker._drift_increment`), no point track claims a position
better than ``position_sigma_floor_m``, speeds are bounded (``max_speed_m_s``), and a track
whose position σ passes its bound (``max_position_sigma_m``, ``max_static_sigma_m``) is
deleted.

**Occluding edges are not tracked**: an edge is where the sensor's line of sight grazes an
object, which for anything round (a pillar, a person) moves with the viewpoint, and for a
box is the box's corner, whose faces the segment and corner tracks already carry (with the
segment ends that the scan saw end). As a fixed point an edge would be a track that drifts
while the vehicle moves, with a NEES no covariance could make consistent; edges are counted
(``edges_ignored``) and dropped.

Track ids are 0, 1, 2, ... in order of creation, never reused.

**Speed.** The per-scan loops over tracks and features (gating costs, the Kalman and IMM
predictions and updates, the decisions, expected visibility, segment ends) are compiled
(:mod:`agent.tracking.tracker_kernels`, :mod:`agent.tracking.visibility_kernels`); their
numpy references are :mod:`agent.tracking.filters` and :mod:`agent.tracking.geometry`, and
the tests compare the two. The benchmark is ``tests/unit/tracking/bench_tracker.py``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment
from scipy.special import chdtri

from agent.arrays import FloatArray
from agent.sim.odometry import OdometryErrorModel
from agent.tracking import tracker_kernels
from agent.tracking.drift import POINTS_PER_AXIS, RelativeDrift
from agent.tracking.geometry import (
    covariances_to_odom,
    lines_to_odom,
    point_drift_noise,
    points_to_odom,
)
from agent.tracking.poses import PoseSample
from agent.tracking.visibility import (
    Beams,
    point_visibility,
    scan_beams,
    segment_ends_seen,
    segment_visibility,
)


def _chi2_quantile(probability: float, dof: int) -> float:
    """The χ² quantile (scipy.stats.chi2.ppf: to the bit at the gates' defaults, within an
    ulp elsewhere) from scipy.special, whose import costs a process 0.2 s where
    scipy.stats costs 0.7 s."""
    return float(chdtri(dof, 1.0 - probability))


KIND_SEGMENT, KIND_CORNER, KIND_EDGE, KIND_CYLINDER = 0, 1, 2, 3
STATUS_TENTATIVE, STATUS_CONFIRMED, STATUS_COASTING = 0, 1, 2
_INFEASIBLE = 1e12
MIN_MODEL_PROBABILITY = 1e-6  # an IMM model at exactly 0 could never come back
SEGMENT_END_SIGMA_M = 0.05  # a seen segment end's σ along the line (TrackSet: why)
# How far a held static track grows for the motion its watch could not rule out
# (TrackerSettings.static_resolution_m): beyond it, whether the thing is still there is for
# the next look to say (expected-visible misses delete it), and a pillar glimpsed for 1 s
# stays tracked through 30 s out of view (max_static_sigma_m 0.6 m less the drift's share).
STATIC_GROWTH_CAP_M = 0.3
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class TrackerSettings:
    """The tracker's parameters (units in the names).

    gate_probability : χ² probability of the validation gates (0.99: one true feature in
        a hundred falls outside its track's gate and starts a tentative track instead).
    exclusion_probability : a feature outside every gate but inside this wider one (χ² 18.4)
        of a track of its kind starts no track: at 0.99 one true feature in a hundred misses
        its track's gate, and would otherwise start a duplicate that then competes with
        the track for the same feature (measured: one duplicate corner in three 30 s runs).
    confirm_hits, confirm_window : M of N: confirmed with M updates within the first N
        scans that could see the track (3 of 5: a mover is confirmed within 0.3-0.5 s of
        entering the window; one clutter detection never is).
    confirm_hits_moving : a tentative cylinder whose CV model is above ``moving_threshold``
        after an update is confirmed with this many updates (never more than
        ``confirm_hits``) within the same window. 3, as everything else: at 2, a walker at
        0.6-0.8 m/s is confirmed on its second update, and ``bench tracking`` (100 scenes,
        3 / 2) measured mover confirmation p95 0.84 / 0.53 s on forward and 0.60 / 0.50 s
        on sweep, forward's moving NEES 3.34 / 3.70 (95 % interval [3.39, 4.66]), but
        sweep's 4.61 / 4.86 ([3.41, 4.64]: a track confirmed on two updates knows its
        velocity less well than its covariance says), sweep's deleted statics seen again
        1 / 2 and fragmentations 180 / 194, false tracks 0.014 / 0.015 a scan. Left at 3
        until the velocity of a two-update track is honest.
    delete_misses : consecutive expected-visible misses that delete a confirmed static
        track (8: about a second of looking straight at where it should be).
    delete_misses_moving, max_coast_moving_s : a moving track (moving probability above
        ``moving_threshold`` when last updated) is deleted after 3 such misses, or 2 s
        without an update: a constant-velocity prediction is not worth more after 2 s of
        a 0.8 m/s mover that may turn.
    hold_static_after_s : a confirmed cylinder that was static when last updated and has
        been unseen this long (0.25 s: two scans) keeps its static model only, its CV
        alternative re-armed from it at each scan (class docstring). Unseen, a free CV
        model spreads at the speed its velocity prior allows (0.9 m σ after 1.6 s), and
        the gate, on the better of the two models, let a coasting pillar's track take a
        mover's feature 2.4 m away (``bench tracking``, sweep, 8 scenes: 2 of its 3 id
        switches); re-armed, a pillar that does start to move is still found from where
        it stood.
    tentative_timeout_s : a tentative track unseen this long is dropped, even out of view
        (0.5 s, the time of the M-of-N window: a tentative cylinder's CV model, with its
        0.5 m/s velocity σ, would otherwise grow a gate that catches any clutter nearby).
    cv_accel_psd_m2_s3 : white-acceleration spectral density of the CV model (m²/s³).
        2.0, for the simulator's movers, which walk back and forth at constant speed and
        turn round at once (a 1.6 m/s step in velocity at 0.8 m/s): measured on such a
        mover (1 m path, 0.8 m/s, 10 seeds, 8 s each), q = 0.2 breaks the track at every
        turn (7 tracks per run) with a velocity NEES far above its dof; q = 2.0 keeps one
        track (1-2) with the 4-dof NEES at 4.2. On straight-line motion it is conservative
        (4-dof NEES about 2.3).
    static_velocity_sigma_m_s : the static model's velocity σ (1 cm/s: "not moving" with
        room for the mixing step; reported for corners and segments too, see
        :class:`TrackSet`).
    initial_velocity_sigma_m_s : a new cylinder's velocity σ (0.5 m/s: movers reach 0.8).
    switch_static_to_moving_per_s, switch_moving_to_static_per_s : IMM switching rates.
        Asymmetric (0.002/s and 0.05/s): a coasting track's model probabilities relax to
        the chain's stationary split, here about 4 % moving, so a static pillar out of view
        does not come back looking like a mover; and a mover's static alternative gets
        0.5 % a scan, which keeps the mixture's spread (a static model lagging v·dt behind)
        from inflating the mover's covariance.
    initial_moving_probability : a new cylinder's CV model probability (0.3).
    moving_threshold : above it (the CV model's probability when last updated) a cylinder
        counts as moving for deletion and is not held static while unseen (0.3). Measured
        on ``bench tracking`` (sweep, 40 scenes): after 3 updates, tracks of static
        cylinders had 0.002 median and 0.04 at the 95th percentile, movers' 0.997 and 0.96
        at the 5th; a track in between is not known to be static. At 0.5, a mover's track
        confirmed at 0.37 and then unseen was held static and kept, σ 3 cm, where the mover
        had been while it walked away (NEES 190-440 for 1.4 s; sweep scene 97). It was 0.1
        until held tracks grew by what their watch could not rule out
        (``static_resolution_m``); since, pillars at 0.13-0.17 were dropped as movers and
        their places seen again (sweep, 100 scenes: 2 of the 4 such deletions), and at 0.3
        the sweep has 2 id switches for 4 and 1 such deletion for 4, its movers' NEES
        (4.61), false tracks (0.014) and forward's figures unchanged.
    min_range_m, max_range_m : the sensor's depth of field.
    visibility_margin_m : beyond the track's 3σ, how much nearer a beam's range must be to
        occlude (5 cm: the cylinders' and walls' own thickness of noise and mixed points).
    corner_footprint_m, corner_min_beams : a corner is expected visible when this many
        clear beams pass within this distance of it on each side (its two faces; the
        extractor needs 5 points and 10 cm per face).
    cylinder_min_beams, segment_min_beams : the same for cylinders (within the radius) and
        segments (crossing the extent).
    segment_frame : where segment features are gated and tracks updated: ``"base"``,
        ``base_link`` at the scan (the tracks taken there and back), or ``"odom"``. A
        line's (α, ρ) about an origin far from it is not linear in α: turned by δα about
        its centroid, its ρ moves by −½ρδα² as well (7 cm for δα = 0.1 rad, a short piece
        2 m ahead, ρ = 14 m), which no first-order covariance carries; a feature's (α, ρ)
        about ``base_link``'s origin has ρ of 1-2.5 m and states that term (``Line.
        reported_cov``), and a track's σ_α is a fraction of a feature's. Measured on
        ``bench tracking --policy forward`` (scenes 0-24): in ``odom`` the tracks of 3-5
        updates had NEES mean 10.5, 30 % above the χ² 95 % point; in ``base_link`` 3.6 and
        18 % (and with ρ's second-order term in the published covariance, see
        :class:`TrackSet`, 2.7 and 14 %); all tracks 2.6 → 1.4 (7.7 → 5.0 %).
    segment_far_margin_m : a segment is expected visible only where it lies this much inside
        the far limit (0.15 m): the extractor leaves out the samples a line puts within 2σ
        of the depth of field's limits, whose errors the limit censors
        (``FeatureSettings.censor_margin_sigma``; σ is 5-6 cm at 2.4 m), so a wall at
        2.4-2.5 m is not reported, and a track of it there is out of range, not missed.
    segment_gap_m : a segment feature gates with a track only if their extents overlap or
        come within this of each other (two walls on one line stay two tracks).
    bright_reflectivity : a segment feature at or above this reflectivity (a docking plate,
        retro-reflective) gates only with tracks whose mean reflectivity is too, and one
        below it only with tracks below it (either unmeasured: any): a plate is mounted
        on a wall, on the wall's line and within its extent, and a wall's features taken
        into the plate's track grew its extent along the wall and moved its centre
        (measured: ``evaluate``'s random run 16 of 96, seed 0, no walkers, the plate
        0.31 m long, its track 1.0 m and its centre 1.9 m along the wall within 5 s).
        2.5: the environment vector's docking threshold
        (:data:`agent.planning.environment.DOCKING_REFLECTIVITY`; a test holds them equal).
    sweep_rate_rad_s : the scan mirror's rate (40° per 0.1 s sweep), which dates each sample
        from its scan angle: a sample ``|θ_last − θ|/rate`` before the scan's stamp (the
        last sample's time). A cylinder is measured at the mean time of its samples (up to
        0.1 s before the stamp: 8 cm for a mover at 0.8 m/s), see :func:`feature_times`.
    timing_tolerance_m : a sample belongs to a cylinder feature when it lies within this of
        the feature's circle (3 cm: about 3σ of the range noise at the far end of the
        depth of field, and less than the gap to anything the extractor keeps apart).
    max_speed_m_s : a prior bound on a cylinder's speed (1.0 m/s: the movers walk at most
        0.8 m/s, and the bound leaves room for the estimate's own noise). A CV model faster
        than this is brought back to it along its direction of motion, the velocity's
        covariance grown by the correction's outer product so that the change is covered:
        without it a coasting mover's velocity, fed by the white-acceleration noise and a
        last bad update, reached 2.6 m/s and carried the track metres off.
    max_position_sigma_m, max_static_sigma_m : a track whose position σ (the larger axis;
        a segment: across its line at either end) exceeds its bound is deleted (counted in
        ``tracks_deleted_uncertain``): 0.25 m for moving cylinders and tentative tracks,
        0.6 m for confirmed static ones. A moving track reaches 0.25 m after about 0.5 s of
        coasting (its CV model's noise), when its 99 % gate already spans 1.5 m and takes
        any neighbour's feature for its own; measured on ``bench tracking`` (4 scenes),
        such coasting movers were most of the false cylinder tracks. A static track's σ
        grows only with the odometry's drift while it is out of view (the drift since its
        last update, :mod:`agent.tracking.drift`), and the tracker is to keep it for the
        next look. Measured on ``bench tracking --policy sweep`` (30 scenes): a static
        bound of 1.0 m left 0.034 false tracks per scan (tracks 0.4-1 m σ whose objects
        drifted past their 99 % gate: the drift's tails are heavier than a Gaussian's) and
        0.5 m 0.015, with the same GOSPA (0.189), 2 and 1 id switches, and no deleted
        track's place seen again in either (``static_deleted_out_of_view_returned`` 0; the
        tracks deleted, 86 and 160, were of features left behind). Over 100 sweep scenes,
        0.35 m against 0.5 m: 0.014 false tracks a scan against 0.029, but 32 deleted
        tracks whose place was seen again against 4 (of 670 and 539 deleted). Measured
        again over 100 scenes with the rest of the tracker as it is now, sweep, 0.5 / 0.6 /
        0.7 m: false tracks 0.014 / **0.018** / 0.023 a scan (the bound is 0.02),
        deleted statics whose place was seen again 1 / **0** / 0 (the one: a corner unseen
        for 15 s, σ at 0.5 m from the odometry's heading drift over 6 m; its place seen
        again 1.3 s later), deletions out of view 559 / 484 / 431, GOSPA 0.184 throughout;
        forward: false tracks 0.0005 at both 0.5 and 0.6, deleted statics seen again 0.
    systematic_drift : the odometry's drift as the error of its motion since each point
        track's last update (True; :mod:`agent.tracking.drift`, under ``odometry_model``),
        or as the increments of a random walk (False); see
        :meth:`Tracker._drift_increment`. Segments always get the random walk's: measured
        on ``bench tracking`` (sweep, 4 scenes), their (α, ρ) NEES was 1.49 (3.8 % above
        the χ² 95 % point) with it and 22 (45 %) with a correlated model. A line fitted
        to a wall errs alike from scan to scan (the same stretch seen from nearly the same
        place), as the points' fits do (``position_sigma_floor_m``), and the random walk's
        larger noise covers that; a measured choice, not a derived one. Measured again
        with segments updated in ``base_link`` (``segment_frame``) and the features
        censored at the far limit (``FeatureSettings.censor_margin_sigma``), scenes 0-24:
        the drift relative to each segment's last update gave a NEES mean over the samples
        of 3.6 (sweep) and 4.3 (forward), the tracks' α errors 1.3-1.5 (sweep) and 1.5-2.1
        (forward) times their σ at every σ from 1 to 50 mrad (3.4 on sweep with no track
        held better than a tenth of its latest feature's covariance); the random walk 1.1
        and 1.4, and over 100 scenes a mean of runs of 1.20 (sweep, below its χ² interval
        [1.63, 2.41]: conservative) and 2.04 (forward). Measured again (scenes 0-29):
        the random walk's coasting segments are 4-7 times too wide (NEES median 0.15-0.29
        at 0.5 s to 10 s unseen, sweep) while just-updated ones are too tight (NEES mean
        4.7: those held below σ_α 2 mrad erred by 2.4 mrad RMS). The relative drift with
        σ_α held to at least 3 mrad after each update (and 3 mm across the line at the
        extent's midpoint) fixed the tight ones (NEES 1.7-1.8 below 3.5 mrad) and gave
        sweep 2.61 (30-run interval [1.35, 2.78]) but forward 4.28: there, segments born
        from a far, short piece 2-4σ off (perception's heavy tail) keep that error for
        their life while their σ shrinks, and the drift since a last update no longer
        hides it (inflating the features' covariance fourfold in the update: 2.84). Over
        100 scenes, after perception's covariances came to cover suspected bends: forward
        4.89 and sweep 2.67 against 1.78 and 1.10 with the random walk, and sweep's false
        tracks 0.030 a scan against 0.014 (tighter coasting segments leave their walls'
        gates: 607 false segment track-scans against 163).
    odometry_model : the odometry's error model (:class:`agent.sim.odometry.
        OdometryErrorModel`: track, wheel scale, ratio and track spreads, slip), the
        vehicle's declared figures; the default is the simulated base's.
    position_sigma_floor_m : after an update, no point track's position is held to better
        than this σ on any axis (3 mm). A feature's error is not independent from scan to
        scan (the same surface, the same bias of the circle or corner fit from the same
        view), so a Kalman filter that averages a hundred scans as if it were claims a
        tenth of a millimetre. Measured on ``bench tracking`` (sweep, 4 scenes): static
        tracks claiming σ below 2 mm had RMS errors of 2.2 mm per axis (below 5 mm: 3.4 mm),
        and their NEES reached 50-150.
    radius_sigma_floor_m : no cylinder track's radius is held to better than this σ (2 cm):
        a mover's fitted radius changes with the sweep's smear and the viewpoint. Cylinders
        gate on position and radius (3 dof, χ² 11.3 at 0.99), so a feature whose radius is
        far from the track's is another object or a wrong fit: measured on ``bench
        tracking`` (forward, scene 45), a 0.06 m circle fitted to a piece of a 0.30 m
        pillar's arc 2.4 m away, 0.3 m from its centre, passed the position gate of the
        pillar's new track (its CV model's) and pulled it 0.3 m off (NEES 590).
    static_resolution_m : how far a cylinder may have moved while it was watched and still
        pass as static (2 cm: about a far cylinder's centre σ). A track held static
        (``hold_static_after_s``) was watched for ``span`` (first to last update), so a
        walker slower than ``static_resolution_m / span`` was not ruled out, and while it
        is unseen (from when it is held) its position variance grows by that speed times
        the time, squared, up to :data:`STATIC_GROWTH_CAP_M`: a pillar watched for seconds
        barely grows (4 mm/s after 5 s), a slow walker glimpsed for 0.4 s on a sweep grows
        5 cm a second rather than staying, tight and static, where it was. Before, on
        ``bench tracking --policy sweep`` (100 scenes), 72 of 2,861 track-mover pairs were
        such tracks: 2.5 % of the pairs, 71 % of the movers' NEES (12 against 3.8 without
        them). Measured, 100 scenes, off / 1 / 2 / 5 cm (uncapped; 2 cm capped gives the
        same figures to the last digit but for 0.01 in the sweep's static NEES): sweep,
        movers' NEES 11.9 / 4.9 / 4.6 / 4.3 (95 % interval [3.41, 4.64]), false tracks a
        scan 0.035 / 0.022 / 0.014 / 0.011, id switches 8 / 6 / 4 / 13, deleted statics
        seen again 4 / 4 / 4 / 16, static NEES 2.11 / 1.51 / 1.29 / 1.04 ([1.63, 2.41]:
        a pillar glimpsed on one pass grows too, so this is conservative); forward, static
        NEES 3.18 / 2.36 / 1.97 / 1.59 ([1.39, 2.73]), id switches 1 / 1 / 0 / 0, false
        tracks 0.0032 / 0.0005 / 0.0005 / 0.0005. 0 turns it off.
    """

    gate_probability: float = 0.99
    exclusion_probability: float = 0.9999
    confirm_hits: int = 3
    confirm_hits_moving: int = 3
    confirm_window: int = 5
    delete_misses: int = 8
    delete_misses_moving: int = 3
    max_coast_moving_s: float = 2.0
    hold_static_after_s: float = 0.25
    tentative_timeout_s: float = 0.5
    cv_accel_psd_m2_s3: float = 2.0
    static_velocity_sigma_m_s: float = 0.01
    initial_velocity_sigma_m_s: float = 0.5
    switch_static_to_moving_per_s: float = 0.002
    switch_moving_to_static_per_s: float = 0.05
    initial_moving_probability: float = 0.3
    moving_threshold: float = 0.3
    min_range_m: float = 0.4
    max_range_m: float = 2.5
    visibility_margin_m: float = 0.05
    corner_footprint_m: float = 0.1
    corner_min_beams: int = 5
    cylinder_min_beams: int = 5
    segment_min_beams: int = 8
    segment_gap_m: float = 0.3
    bright_reflectivity: float = 2.5
    segment_far_margin_m: float = 0.15
    segment_frame: str = "base"
    sweep_rate_rad_s: float = math.radians(40.0) / 0.1
    timing_tolerance_m: float = 0.03
    max_speed_m_s: float = 1.0
    max_position_sigma_m: float = 0.25
    max_static_sigma_m: float = 0.6
    systematic_drift: bool = True
    odometry_model: OdometryErrorModel = field(default_factory=OdometryErrorModel)
    position_sigma_floor_m: float = 0.003
    radius_sigma_floor_m: float = 0.05
    static_resolution_m: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 < self.gate_probability <= self.exclusion_probability < 1.0:
            raise ValueError(
                "need 0 < gate_probability <= exclusion_probability < 1, got "
                f"{self.gate_probability} and {self.exclusion_probability}"
            )
        if self.confirm_hits_moving < 1:
            raise ValueError(
                f"confirm_hits_moving must be at least 1, got {self.confirm_hits_moving}"
            )
        if not 1 <= self.confirm_hits <= self.confirm_window:
            raise ValueError(
                f"need 1 <= confirm_hits <= confirm_window, got "
                f"{self.confirm_hits} of {self.confirm_window}"
            )
        for name in ("delete_misses", "delete_misses_moving", "corner_min_beams",
                     "cylinder_min_beams", "segment_min_beams"):  # fmt: skip
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        for name in ("max_coast_moving_s", "hold_static_after_s", "tentative_timeout_s",
                     "cv_accel_psd_m2_s3",
                     "sweep_rate_rad_s", "timing_tolerance_m", "max_speed_m_s",
                     "max_position_sigma_m", "max_static_sigma_m", "position_sigma_floor_m",
                     "radius_sigma_floor_m",
                     "static_velocity_sigma_m_s", "initial_velocity_sigma_m_s",
                     "switch_static_to_moving_per_s", "switch_moving_to_static_per_s",
                     "min_range_m", "max_range_m", "corner_footprint_m",
                     "bright_reflectivity"):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and positive, got {value}")
        if self.segment_frame not in ("base", "odom"):
            raise ValueError(f"segment_frame must be 'base' or 'odom', got {self.segment_frame!r}")
        for name in ("visibility_margin_m", "segment_gap_m", "segment_far_margin_m",
                     "static_resolution_m"):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")
        for name in ("initial_moving_probability", "moving_threshold"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise ValueError(f"{name} must be in (0, 1), got {getattr(self, name)}")
        if self.min_range_m >= self.max_range_m:
            raise ValueError(f"min_range_m {self.min_range_m} must be below {self.max_range_m}")

    @property
    def gate_chi2(self) -> float:
        """The gate on d² for 2 degrees of freedom (9.21 at 0.99)."""
        return float(_chi2_quantile(self.gate_probability, 2))


@dataclass(frozen=True)
class FeatureBatch:
    """One scan's features in ``base_link`` (as the ``features`` message carries them):
    kind (k,) uint8; params (k, 3); covariance (k, 3, 3); endpoints (k, 2, 2);
    reflectivity (k,)."""

    kind: NDArray[np.uint8]
    params: FloatArray
    covariance: FloatArray
    endpoints: FloatArray
    reflectivity: FloatArray

    def select(self, mask: BoolArray | IntArray | slice) -> FeatureBatch:
        """The features a mask, indices or slice picks."""
        return FeatureBatch(
            self.kind[mask], self.params[mask], self.covariance[mask], self.endpoints[mask],
            self.reflectivity[mask],
        )  # fmt: skip


@dataclass(frozen=True)
class ScanView:
    """The filtered scan's samples the tracker reads (``base_link`` at the reference time)."""

    points_xy: FloatArray
    origin_xy: FloatArray
    scan_angle_rad: FloatArray
    range_m: FloatArray
    flag: NDArray[np.uint8]


def valid_features(batch: FeatureBatch) -> BoolArray:
    """(k,) which features are well formed: a known kind; finite parameters and covariance
    within its degrees of freedom; a positive-definite covariance (by its leading minors),
    symmetric to 1e-9 of its diagonal's scale (as round-off leaves it); a segment's end
    points finite; a cylinder's radius positive."""
    return tracker_kernels.valid_features(
        np.ascontiguousarray(batch.kind, dtype=np.uint8),
        np.ascontiguousarray(batch.params, dtype=np.float64),
        np.ascontiguousarray(batch.covariance, dtype=np.float64),
        np.ascontiguousarray(batch.endpoints, dtype=np.float64),
    )


def feature_times(
    centre_xy: FloatArray, radius_m: FloatArray, scan: ScanView | None, settings: TrackerSettings
) -> tuple[FloatArray, FloatArray]:
    """When each cylinder feature was measured: ``tau`` (k,) s before the scan's stamp, the
    mean time of its samples, and ``var`` (k,) s², the variance of their times.

    A feature's samples are the scan's valid samples within ``timing_tolerance_m`` of its
    circle (``centre_xy`` (k, 2), ``radius_m`` (k,), ``base_link``); each is dated from its
    scan angle at ``sweep_rate_rad_s`` back from the last sample's (the stamp). A feature
    with no such sample (or no scan) gets 0 and 0: the stamp, as before this was known.
    """
    k = centre_xy.shape[0]
    if scan is None or k == 0 or scan.scan_angle_rad.size == 0:
        return np.zeros(k), np.zeros(k)
    ok = (scan.flag == 0) & np.isfinite(scan.points_xy).all(axis=1)
    age = np.abs(scan.scan_angle_rad[-1] - scan.scan_angle_rad[ok]) / settings.sweep_rate_rad_s
    return tracker_kernels.feature_times(
        np.ascontiguousarray(centre_xy, dtype=np.float64),
        np.ascontiguousarray(radius_m, dtype=np.float64),
        np.ascontiguousarray(scan.points_xy[ok], dtype=np.float64),
        age,
        settings.timing_tolerance_m,
    )


@dataclass(frozen=True)
class TrackSet:
    """All tracks after a scan, as the ``tracks/2`` message carries them (frame ``odom``).

    For corners and segments (static by model) the velocity is zero with a variance of
    ``static_velocity_sigma_m_s²``, so that the 4×4 covariance stays positive definite for
    consumers that invert it. A segment's position covariance is its line's across the line
    (from (α, ρ)) and, along it, that of the extent's midpoint: (5 cm)² when both ends
    were seen, else the extent's length²/12 (the midpoint of what has been looked at is no
    physical point). A segment's ``params_covariance`` over (α, ρ) in ``odom`` has ρ's
    second-order error, ``½ρ²σ_α⁴``, in ρ's variance (:func:`tracker_kernels.
    segment_outputs`). ``information_bits``: what the track's updates have told so far,
    the sum over them of ``½·log₂(det P⁻ / det P⁺)`` of its position (a line's (α, ρ)).
    """

    track_id: IntArray
    kind: NDArray[np.uint8]
    status: NDArray[np.uint8]
    state: FloatArray
    covariance: FloatArray
    params: FloatArray
    params_covariance: FloatArray
    extent: FloatArray
    end_seen: NDArray[np.uint8]
    reflectivity: FloatArray
    moving_probability: FloatArray
    last_seen_ns: IntArray
    hits: IntArray
    information_bits: FloatArray

    def __len__(self) -> int:
        return int(self.track_id.size)


def _by_kind(features: FeatureBatch, ok: BoolArray) -> dict[int, FeatureBatch]:
    """The well-formed features (``ok``) of each kind, each in its order: one stable sort
    by kind, then slices."""
    good = np.flatnonzero(ok)
    batch = features.select(good[np.argsort(features.kind[good], kind="stable")])
    start = np.searchsorted(batch.kind, np.arange(KIND_CYLINDER + 2, dtype=np.uint8)).tolist()
    return {
        kd: batch.select(slice(start[kd], start[kd + 1]))
        for kd in (KIND_SEGMENT, KIND_CORNER, KIND_CYLINDER)
    }


# ------------------------------------------------------------------------------ track banks
_COMMON: dict[str, tuple[tuple[int, ...], type]] = {
    "track_id": ((), np.int64),
    "hits": ((), np.int64),
    "visible_scans": ((), np.int64),
    "misses": ((), np.int64),
    "last_seen_ns": ((), np.int64),
    "refl_sum": ((), np.float64),
    "refl_n": ((), np.int64),
    "confirmed": ((), np.bool_),
    "updated": ((), np.bool_),
    # Position noise added for the odometry's drift since the last update (its x, y block).
    "drift": ((3, 3), np.float64),
    # Information the updates brought so far, bits (tracker_kernels.add_information).
    "bits": ((), np.float64),
}


class _Bank:
    """Struct of arrays over the tracks of one kind."""

    def __init__(self, specific: Mapping[str, tuple[tuple[int, ...], type]]) -> None:
        self.spec = {**_COMMON, **specific}
        self.a: dict[str, NDArray[np.generic]] = {
            name: np.zeros((0, *shape), dtype=dt) for name, (shape, dt) in self.spec.items()
        }

    def __len__(self) -> int:
        return int(self.a["track_id"].size)

    def f(self, name: str) -> FloatArray:
        return self.a[name]  # type: ignore[return-value]

    def i(self, name: str) -> IntArray:
        return self.a[name]  # type: ignore[return-value]

    def b(self, name: str) -> BoolArray:
        return self.a[name]  # type: ignore[return-value]

    def keep(self, mask: BoolArray) -> None:
        if not mask.all():
            self.a = {name: arr[mask] for name, arr in self.a.items()}

    def append(self, new: dict[str, NDArray[np.generic]]) -> None:
        n = next(iter(new.values())).shape[0]
        if n == 0:
            return
        for name, (shape, dt) in self.spec.items():
            value = new.get(name)
            if value is None:
                value = np.zeros((n, *shape), dtype=dt)
            self.a[name] = np.concatenate([self.a[name], np.asarray(value, dtype=dt)])


@dataclass
class _Assignment:
    tracks: IntArray
    features: IntArray
    unassigned: IntArray  # features with no track
    in_other_gate: BoolArray  # per unassigned feature: inside some track's gate
    best_track: IntArray  # per unassigned feature: the track of least cost among gated
    near_track: BoolArray  # per unassigned feature: inside some track's exclusion gate


def _alike_brightness(
    refl_sum: FloatArray, refl_n: IntArray, refl: FloatArray, bright: float
) -> BoolArray:
    """(k, m): whether each track (its reflectivity summed over ``refl_n`` features) and
    each feature (``refl`` (m,)) lie on the same side of ``bright``; true where either is
    unmeasured (``TrackerSettings.bright_reflectivity``)."""
    track = refl_sum / np.maximum(refl_n, 1)
    known = (refl_n > 0)[:, None] & np.isfinite(refl)[None, :]
    same = (track >= bright)[:, None] == (refl >= bright)[None, :]
    return np.asarray(~known | same, dtype=np.bool_)


def _assign(cost: FloatArray, gated: BoolArray, near: BoolArray) -> _Assignment:
    """Global assignment of features (columns) to tracks (rows) within the gates; ``near``
    (as ``gated``, a wider gate) marks the unassigned features too close to a track to start
    one of their own."""
    k, m = cost.shape
    if k and m and gated.any():
        rows, cols = linear_sum_assignment(np.where(gated, cost, _INFEASIBLE))
    else:
        rows = cols = np.zeros(0, dtype=np.int64)
    return _Assignment(
        *tracker_kernels.assignment_rest(
            np.asarray(rows, dtype=np.int64),
            np.asarray(cols, dtype=np.int64),
            cost,
            np.ascontiguousarray(gated),
            np.ascontiguousarray(near),
        )
    )


# ----------------------------------------------------------------------------------- tracker
@dataclass
class TrackerCounters:
    """What the tracker dropped or made, for the stage's heartbeat."""

    scans: int = 0
    features_malformed: int = 0
    edges_ignored: int = 0
    scans_out_of_order: int = 0
    tracks_created: int = 0
    tracks_deleted: int = 0
    tracks_deleted_uncertain: int = 0
    speeds_bounded: int = 0
    tracks_confirmed: int = 0
    extents_merged: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(vars(self))


@dataclass(eq=False)
class Tracker:
    """Tracks of segments, corners and cylinders in ``odom`` (module docstring)."""

    settings: TrackerSettings = field(default_factory=TrackerSettings)
    counters: TrackerCounters = field(default_factory=TrackerCounters)

    def __post_init__(self) -> None:
        point = {"x": ((2,), np.float64), "P": ((2, 2), np.float64)}
        self.corners = _Bank(point)
        self.segments = _Bank({**point, "ends": ((2, 2), np.float64), "seen": ((2,), np.bool_)})
        self.cylinders = _Bank(
            {
                "xm": ((2, 4), np.float64),
                "Pm": ((2, 4, 4), np.float64),
                "mu": ((2,), np.float64),
                "mu_seen": ((), np.float64),
                "r": ((), np.float64),
                "r_var": ((), np.float64),
                "first_seen_ns": ((), np.int64),
            }
        )
        self._next_id = 0
        self._drift = RelativeDrift(self.settings.odometry_model, POINTS_PER_AXIS)
        # The drift's hypotheses per *epoch*, a scan at which point tracks were updated or
        # made (they start from that scan's pose): every track last updated at one scan
        # shares them, so the work goes with the scans since, not with the tracks
        # (_advance_drift). Sorted by stamp; a track finds its own by its last_seen_ns.
        # The first _epochs rows of arrays that grow by doubling (one row a scan is added).
        self._epochs = 0
        self._epoch_ns = np.zeros(16, dtype=np.int64)
        self._epoch_hyp, self._epoch_slip = self._drift.start(np.zeros(3), 16)
        self._epoch_cov = np.zeros((0, 3, 3))  # of the first _epochs, this scan
        self._pose_now = np.zeros(3)
        self._last_ns: int | None = None
        self._last_pose: PoseSample | None = None
        self._gate = self.settings.gate_chi2
        st = self.settings
        rate_up, rate_down = st.switch_static_to_moving_per_s, st.switch_moving_to_static_per_s
        moving = rate_up / (rate_up + rate_down)
        self._stationary = np.array([1.0 - moving, moving])
        self._exclusion = float(_chi2_quantile(self.settings.exclusion_probability, 2))
        # Cylinders gate on position and radius.
        self._gate_3 = float(_chi2_quantile(self.settings.gate_probability, 3))
        self._exclusion_3 = float(_chi2_quantile(self.settings.exclusion_probability, 3))

    # ------------------------------------------------------------------ public
    def __len__(self) -> int:
        return len(self.corners) + len(self.segments) + len(self.cylinders)

    @property
    def last_stamp_ns(self) -> int | None:
        """The stamp of the last scan taken (None before the first)."""
        return self._last_ns

    def update(
        self, stamp_ns: int, pose: PoseSample, features: FeatureBatch, scan: ScanView | None
    ) -> TrackSet:
        """Take one scan's features (module docstring) and return every track after it.

        ``pose``: the odometry pose and covariance at ``stamp_ns`` (the scan's reference
        time). ``scan``: the filtered scan the features came from, for expected visibility
        and segment ends (None: nothing is expected visible and no end counts as seen).
        A scan not later than the last one is counted and changes nothing.
        """
        if self._last_ns is not None and stamp_ns <= self._last_ns:
            self.counters.scans_out_of_order += 1
            return self.tracks()
        self.counters.scans += 1
        dt = 0.0 if self._last_ns is None else (stamp_ns - self._last_ns) * 1e-9
        P_pose = pose.pose
        if self._last_pose is None:
            delta = np.zeros((3, 3))
        else:
            d = P_pose[:2] - self._last_pose.pose[:2]
            delta = tracker_kernels.pose_noise_increment(
                np.ascontiguousarray(self._last_pose.covariance, dtype=np.float64),
                np.ascontiguousarray(pose.covariance, dtype=np.float64),
                float(d[0]),
                float(d[1]),
            )
        self._advance_drift(pose)
        self._last_ns, self._last_pose = stamp_ns, pose

        ok = valid_features(features)
        self.counters.features_malformed += int((~ok).sum())
        cov = features.covariance
        features = dataclasses.replace(features, covariance=0.5 * (cov + cov.transpose(0, 2, 1)))
        edges = ok & (features.kind == KIND_EDGE)
        self.counters.edges_ignored += int(edges.sum())
        st = self.settings
        beams = None
        if scan is not None:
            beams = scan_beams(
                scan.points_xy, scan.origin_xy, scan.scan_angle_rad, scan.range_m, scan.flag,
                st.min_range_m, st.max_range_m,
            )  # fmt: skip
        vxy = P_pose[:2]
        for bank in (self.corners, self.segments, self.cylinders):
            bank.a["updated"] = np.zeros(len(bank), dtype=bool)

        # Segments keep the random walk's increment (TrackerSettings.systematic_drift).
        self._predict_points(
            self.corners, self._drift_increment(self.corners, delta, self.corners.f("x"), vxy), vxy
        )
        self._predict_segments(delta, vxy)
        cyl_xy = self.cylinders.f("xm")[:, 0, :2]  # the static model's: the drift is for it
        self._predict_cylinders(
            dt, self._drift_increment(self.cylinders, delta, cyl_xy, vxy), vxy, stamp_ns
        )

        by_kind = _by_kind(features, ok)
        self._corners_step(by_kind[KIND_CORNER], pose, stamp_ns)
        self._segments_step(by_kind[KIND_SEGMENT], pose, stamp_ns, scan)
        self._cylinders_step(by_kind[KIND_CYLINDER], pose, stamp_ns, scan)
        self._bound_speeds()
        self._book_keep(pose, beams, stamp_ns)
        self._keep_epochs(stamp_ns)
        return self.tracks()

    def _bound_speeds(self) -> None:
        """Bring CV models faster than ``max_speed_m_s`` back to it (TrackerSettings)."""
        bank = self.cylinders
        if len(bank):
            self.counters.speeds_bounded += tracker_kernels.bound_speeds(
                bank.f("xm"), bank.f("Pm"), self.settings.max_speed_m_s
            )

    # ---------------------------------------------------------------- predict
    def _advance_drift(self, pose: PoseSample) -> None:
        """Move the drift's hypotheses of every epoch with the odometry's motion since the
        last scan (:class:`agent.tracking.drift.RelativeDrift`) and take their covariance."""
        now = np.asarray(pose.pose, dtype=np.float64)[:3]
        n = self._epochs
        if self._last_pose is not None and n and self.settings.systematic_drift:
            hyp, slip = self._epoch_hyp[:n], self._epoch_slip[:n]
            self._drift.advance_in_place(
                hyp, slip, np.asarray(self._last_pose.pose, dtype=np.float64)[:3], now
            )
            self._epoch_cov = self._drift.covariance(hyp, slip)
        self._pose_now = now.copy()

    def _keep_epochs(self, stamp_ns: int) -> None:
        """Drop the epochs no point track refers to; start this scan's if one does."""
        if not self.settings.systematic_drift:
            return
        if self._epochs == self._epoch_ns.size:  # room for this scan's
            grow = self._epoch_ns.size
            hyp, slip = self._drift.start(np.zeros(3), grow)
            self._epoch_ns = np.concatenate([self._epoch_ns, np.zeros(grow, dtype=np.int64)])
            self._epoch_hyp = np.concatenate([self._epoch_hyp, hyp])
            self._epoch_slip = np.concatenate([self._epoch_slip, slip])
        self._epochs = tracker_kernels.keep_epochs(
            self._epoch_ns, self._epoch_hyp, self._epoch_slip, self._epochs,
            self.corners.i("last_seen_ns"), self.cylinders.i("last_seen_ns"), stamp_ns,
            self._pose_now,
        )  # fmt: skip

    def _drift_increment(
        self, bank: _Bank, delta: FloatArray, xy: FloatArray, vxy: FloatArray
    ) -> FloatArray:
        """(k, 3, 3) the odometry's pose noise to add to each track of ``bank`` this scan;
        ``xy`` (k, 2) the tracks' positions and ``vxy`` the vehicle's, in ``odom``.

        The odometry's error is mostly systematic (wheel scale and track errors fixed for
        a run: :mod:`agent.sim.odometry`), so a track must carry the error of the
        odometry's motion since its last update, whose covariance ``Σ_rel`` the published
        pose covariances do not give (:mod:`agent.tracking.drift` propagates it per
        epoch, the scan of the track's last update). It is mapped to the track's position
        with the lever arm of *now*,
        ``J·Σ_rel·Jᵀ``: a heading error made while the vehicle stood next to a track moves
        it as far as the vehicle is from it now (adding ``J·ΔΣ·Jᵀ`` scan by scan instead
        would map the early heading error through the early, short lever: measured on
        ``bench tracking``, a corner 16 s unseen was 0.86 m off with σ 0.27 m). Each track
        keeps the position noise added since its last update (``drift``) and gets the
        positive part of ``J·Σ_rel·Jᵀ`` minus it, returned as a pose noise with only its
        (x, y) block set (``J = [I | L]`` maps it to itself). With ``systematic_drift``
        off, every track gets ``delta``, the increment ``Σ_now − F·Σ_then·Fᵀ`` of a random
        walk.
        """
        k = len(bank)
        if not self.settings.systematic_drift:
            return np.broadcast_to(delta, (k, 3, 3)).copy()
        if not k:
            return np.zeros((0, 3, 3))
        return tracker_kernels.drift_increment(
            np.ascontiguousarray(xy), vxy, self._epoch_cov,
            np.searchsorted(self._epoch_ns[: self._epochs], bank.i("last_seen_ns")),
            bank.f("drift"),
        )  # fmt: skip

    def _predict_points(self, bank: _Bank, delta: FloatArray, vxy: FloatArray) -> None:
        if not len(bank):
            return
        if self.settings.systematic_drift:  # only an (x, y) block: J = [I | L] maps it to itself
            bank.a["P"] = bank.f("P") + delta[:, :2, :2]
        else:
            bank.a["P"] = bank.f("P") + point_drift_noise(bank.f("x"), vxy, delta)

    def _predict_segments(self, delta: FloatArray, vxy: FloatArray) -> None:
        bank = self.segments
        if len(bank):
            tracker_kernels.add_line_drift(bank.f("P"), bank.f("x"), vxy, delta)

    def _switching(self, dt: float) -> FloatArray:
        st = self.settings
        p01 = 1.0 - math.exp(-st.switch_static_to_moving_per_s * dt)
        p10 = 1.0 - math.exp(-st.switch_moving_to_static_per_s * dt)
        return np.array([[1.0 - p01, p01], [p10, 1.0 - p10]])

    def _predict_cylinders(
        self, dt: float, delta: FloatArray, vxy: FloatArray, stamp_ns: int
    ) -> None:
        bank = self.cylinders
        if not len(bank):
            return
        st = self.settings
        # A static track unseen for long (``hold_static_after_s``) keeps only its static
        # model: the CV alternative, predicted for tens of seconds, would spread over metres
        # and swamp the estimate (module docstring). It is re-armed from the static model
        # at every scan, with the velocity prior of a new track and the chain's stationary
        # probability, so that the next update can still find a mover.
        unseen_s = (stamp_ns - bank.i("last_seen_ns")) * 1e-9
        hold_after = np.where(bank.b("confirmed"), st.hold_static_after_s, st.max_coast_moving_s)
        held = (unseen_s > hold_after) & (bank.f("mu_seen") <= st.moving_threshold)
        x, P, c = tracker_kernels.imm_predict(
            bank.f("xm"), bank.f("Pm"), bank.f("mu"), self._switching(dt), dt,
            st.cv_accel_psd_m2_s3, st.static_velocity_sigma_m_s**2,
            np.ascontiguousarray(vxy, dtype=np.float64), delta, held, self._stationary,
            st.initial_velocity_sigma_m_s**2,
        )  # fmt: skip
        if st.static_resolution_m > 0.0 and held.any():
            # What the static model could not rule out: a walker slower than the resolution
            # over the time it was watched, moving on since (TrackerSettings).
            span_s = (bank.i("last_seen_ns")[held] - bank.i("first_seen_ns")[held]) * 1e-9
            watch = st.static_resolution_m / np.maximum(span_s, 0.1)
            speed = np.minimum(watch, st.max_speed_m_s)
            until = STATIC_GROWTH_CAP_M / speed  # unseen this long, it stops growing
            now = np.minimum(unseen_s[held], until)
            before = np.minimum(np.maximum(unseen_s[held] - dt, 0.0), until)
            grow = speed**2 * (now**2 - before**2)
            P[held, :, 0, 0] += grow[:, None]
            P[held, :, 1, 1] += grow[:, None]
        bank.a["xm"], bank.a["Pm"], bank.a["mu"] = x, P, c

    # ----------------------------------------------------------------- corners
    def _corners_step(self, feats: FeatureBatch, pose: PoseSample, stamp_ns: int) -> None:
        bank = self.corners
        if not feats.kind.size:
            return
        z = points_to_odom(pose.pose, feats.params[:, :2])
        R = covariances_to_odom(pose.pose, feats.covariance[:, :2, :2])
        x, P = bank.f("x"), bank.f("P")
        d2, cost = tracker_kernels.point_costs(z, R, x, P)
        a = _assign(cost, d2 <= self._gate, d2 <= self._exclusion)
        if a.tracks.size:
            t, j = a.tracks, a.features
            before = tracker_kernels.position_log_dets(P, t)
            tracker_kernels.kf_update(x, P, t, z[j] - x[t], R[j], False)
            tracker_kernels.floor_position(P, t, self.settings.position_sigma_floor_m)
            after = tracker_kernels.position_log_dets(P, t)
            tracker_kernels.add_information(bank.f("bits"), t, before, after)
            self._hit(bank, t, feats.reflectivity[j], stamp_ns)
        new = a.unassigned[~a.in_other_gate & ~a.near_track]
        self._create(bank, {"x": z[new], "P": R[new]}, feats.reflectivity[new], stamp_ns)

    # ---------------------------------------------------------------- segments
    def _segments_step(
        self, feats: FeatureBatch, pose: PoseSample, stamp_ns: int, scan: ScanView | None
    ) -> None:
        bank = self.segments
        st = self.settings
        m = feats.kind.size
        if not m:
            return
        if scan is not None:
            seen_m = segment_ends_seen(
                feats.endpoints, feats.params[:, 0], feats.params[:, 1], scan.points_xy,
                scan.origin_xy, scan.range_m, scan.flag, st.max_range_m,
            )  # fmt: skip
        else:
            seen_m = np.zeros((m, 2), dtype=bool)
        alpha, rho, R = lines_to_odom(
            pose.pose, feats.params[:, 0], feats.params[:, 1], feats.covariance[:, :2, :2]
        )
        ends_m = points_to_odom(pose.pose, feats.endpoints.reshape(-1, 2)).reshape(-1, 2, 2)
        x, P = bank.f("x"), bank.f("P")
        k = len(bank)
        # Gated and updated in base_link, near the lines (TrackerSettings.segment_frame):
        # the tracks taken there, each feature written within a quarter turn of each
        # track's α.
        if st.segment_frame == "base":
            xb_a, xb_r, Pb = lines_to_odom(_inverse_pose(pose.pose), x[:, 0], x[:, 1], P)
            xb = np.ascontiguousarray(np.stack([xb_a, xb_r], axis=1))
            za, zr = feats.params[:, 0], feats.params[:, 1]
            Rz = np.ascontiguousarray(feats.covariance[:, :2, :2])
        else:
            xb, Pb, za, zr, Rz = x, P, alpha, rho, R
        d2, cost, nu, flip = tracker_kernels.line_costs(
            np.ascontiguousarray(za), np.ascontiguousarray(zr), Rz, xb, Pb
        )
        gated = d2 <= self._gate
        near = d2 <= self._exclusion
        if k and m:  # extents must overlap (or nearly): along each track's line
            gated &= tracker_kernels.extents_near(x, bank.f("ends"), ends_m, st.segment_gap_m)
            # A plate and the wall it is on stay apart (``bright_reflectivity``).
            alike = _alike_brightness(
                bank.f("refl_sum"), bank.i("refl_n"), feats.reflectivity, st.bright_reflectivity
            )
            gated &= alike
            near &= alike
        a = _assign(cost, gated, near)
        if a.tracks.size:
            t, j = a.tracks, a.features
            Rj = Rz[j].copy()
            sign = np.where(flip[t, j], -1.0, 1.0)
            Rj[:, 0, 1] *= sign
            Rj[:, 1, 0] *= sign
            # (α, ρ)'s determinant is the same in either frame (a unit Jacobian).
            before = tracker_kernels.position_log_dets(Pb, t)
            tracker_kernels.kf_update(xb, Pb, t, nu[t, j], Rj, True)
            after = tracker_kernels.position_log_dets(Pb, t)
            tracker_kernels.add_information(bank.f("bits"), t, before, after)
            if st.segment_frame == "base":  # back to odom
                ua, ur, uP = lines_to_odom(pose.pose, xb[t, 0], xb[t, 1], Pb[t])
                x[t, 0], x[t, 1], P[t] = ua, ur, uP
            self._merge_extents(t, ends_m[j], seen_m[j])
            self._hit(bank, t, feats.reflectivity[j], stamp_ns)
        merge = a.unassigned[a.in_other_gate]
        if merge.size:
            self.counters.extents_merged += int(merge.size)
            self._merge_extents(a.best_track[a.in_other_gate], ends_m[merge], seen_m[merge])
        new = a.unassigned[~a.in_other_gate & ~a.near_track]
        if new.size:
            xs, ends, seen = tracker_kernels.new_segments(alpha, rho, ends_m, seen_m, new)
            self._create(
                bank,
                {"x": xs, "P": R[new], "ends": ends, "seen": seen},
                feats.reflectivity[new],
                stamp_ns,
            )

    def _merge_extents(self, t: IntArray, ends_m: FloatArray, seen_m: BoolArray) -> None:
        """Grow (or, at ends the scan saw, set) the extents of tracks ``t`` (module doc)."""
        bank = self.segments
        tracker_kernels.merge_extents(
            bank.f("x"), bank.f("ends"), bank.b("seen"), t, np.ascontiguousarray(ends_m),
            np.ascontiguousarray(seen_m),
        )  # fmt: skip

    # --------------------------------------------------------------- cylinders
    def _cylinders_step(
        self, feats: FeatureBatch, pose: PoseSample, stamp_ns: int, scan: ScanView | None
    ) -> None:
        bank = self.cylinders
        st = self.settings
        if not feats.kind.size:
            return
        z = points_to_odom(pose.pose, feats.params[:, :2])
        R = covariances_to_odom(pose.pose, feats.covariance[:, :2, :2])
        # Each feature at its own samples' time (``feature_times``): the update takes it as
        # a measurement of the position tau before the stamp, H = [I, -tau*I].
        tau, smear = feature_times(feats.params[:, :2], feats.params[:, 2], scan, st)
        # Gate and cost on the better of the two models: a mover gates on its CV model
        # even while the static one still has most of the probability.
        # And on the radius (3 dof): a feature of another radius is another object, or a
        # wrong fit (radius_sigma_floor_m).
        rz = np.ascontiguousarray(feats.params[:, 2])
        rv = np.ascontiguousarray(feats.covariance[:, 2, 2])
        d2, cost = tracker_kernels.cylinder_costs(
            z, R, tau, smear, bank.f("xm"), bank.f("Pm"), st.cv_accel_psd_m2_s3, rz, rv,
            bank.f("r"), bank.f("r_var"),
        )  # fmt: skip
        a = _assign(cost, d2 <= self._gate_3, d2 <= self._exclusion_3)
        if a.tracks.size:
            t, j = a.tracks, a.features
            before = _mixture_log_dets(bank, t)
            tracker_kernels.imm_update_timed(
                bank.f("xm"), bank.f("Pm"), bank.f("mu"), t, z[j], R[j], tau[j], smear[j],
                st.cv_accel_psd_m2_s3, MIN_MODEL_PROBABILITY,
            )  # fmt: skip
            # Both models' (x, y) blocks: rows 2t and 2t + 1 of the (2k, 4, 4) view.
            models = (2 * t[:, None] + np.arange(2)).ravel()
            tracker_kernels.floor_position(
                bank.f("Pm").reshape(-1, 4, 4), models, st.position_sigma_floor_m
            )
            after = _mixture_log_dets(bank, t)
            tracker_kernels.add_information(bank.f("bits"), t, before, after)
            bank.f("mu_seen")[t] = bank.f("mu")[t, 1]
            tracker_kernels.fuse_radius(
                bank.f("r"), bank.f("r_var"), t, rz[j], rv[j], st.radius_sigma_floor_m**2
            )
            self._hit(bank, t, feats.reflectivity[j], stamp_ns)
        new = a.unassigned[~a.in_other_gate & ~a.near_track]
        n = new.size
        if n:
            # The CV model starts at the feature's own time, tau before the stamp, and is
            # predicted to the stamp: its unknown velocity spreads the position by
            # tau·σ_v (8 cm at the window's first edge for a 0.8 m/s mover), with the
            # matching position-velocity covariance, and the white acceleration adds Q(tau).
            x0, P0 = tracker_kernels.new_cylinders(
                z, R, tau, new, st.static_velocity_sigma_m_s**2,
                st.initial_velocity_sigma_m_s**2, st.cv_accel_psd_m2_s3,
            )  # fmt: skip
            p = st.initial_moving_probability
            self._create(
                bank,
                {
                    "xm": x0,
                    "Pm": P0,
                    "mu": np.tile([1.0 - p, p], (n, 1)),
                    "mu_seen": np.full(n, p),
                    "r": rz[new],
                    "r_var": np.maximum(rv[new], st.radius_sigma_floor_m**2),
                    "first_seen_ns": np.full(n, stamp_ns, dtype=np.int64),
                },
                feats.reflectivity[new],
                stamp_ns,
            )

    # --------------------------------------------------------------- bookkeeping
    def _hit(self, bank: _Bank, t: IntArray, refl: FloatArray, stamp_ns: int) -> None:
        # The drift since the last update cleared: its epoch is now this scan's
        # (_keep_epochs).
        tracker_kernels.hit(
            t, np.ascontiguousarray(refl, dtype=np.float64), stamp_ns, bank.f("drift"),
            bank.i("hits"), bank.b("updated"), bank.i("last_seen_ns"), bank.f("refl_sum"),
            bank.i("refl_n"),
        )  # fmt: skip

    def _create(
        self,
        bank: _Bank,
        arrays: dict[str, NDArray[np.generic]],
        refl: FloatArray,
        stamp_ns: int,
    ) -> None:
        n = refl.size
        if not n:
            return
        ok = np.isfinite(refl)
        ids = np.arange(self._next_id, self._next_id + n, dtype=np.int64)
        self._next_id += n
        self.counters.tracks_created += n
        bank.append(
            {
                **arrays,
                "track_id": ids,
                "hits": np.ones(n, dtype=np.int64),
                "visible_scans": np.ones(n, dtype=np.int64),
                "last_seen_ns": np.full(n, stamp_ns, dtype=np.int64),
                "refl_sum": np.where(ok, refl, 0.0),
                "refl_n": ok.astype(np.int64),
                "confirmed": np.full(n, self.settings.confirm_hits <= 1),
                "updated": np.ones(n, dtype=bool),
            }
        )

    def _book_keep(self, pose: PoseSample, beams: Beams | None, stamp_ns: int) -> None:
        st = self.settings
        # Expected visibility of corners and cylinders in one pass; lost: position σ above
        # max_position_sigma_m (moving cylinders, tentative tracks) or max_static_sigma_m
        # (confirmed static ones; TrackerSettings).
        nc = len(self.corners)
        cyl = self.cylinders
        points, near, footprint, sigma, min_beams, two_sided, lost = (
            tracker_kernels.point_view_inputs(
                self.corners.f("x"), self.corners.f("P"), self.corners.b("confirmed"),
                cyl.f("xm"), cyl.f("Pm"), cyl.f("mu"), cyl.f("r"), cyl.f("mu_seen"),
                cyl.b("confirmed"), np.ascontiguousarray(pose.pose[:3], dtype=np.float64),
                st.corner_footprint_m, st.corner_min_beams, st.cylinder_min_beams,
                st.moving_threshold, st.max_static_sigma_m, st.max_position_sigma_m,
            )
        )  # fmt: skip
        view = point_visibility(
            beams, points, near, footprint, sigma, min_beams, two_sided, st.min_range_m,
            st.max_range_m, st.visibility_margin_m,
        )  # fmt: skip
        self._decide(self.corners, view.visible[:nc], stamp_ns, lost[:nc])
        seg = self.segments
        seg_bound = np.where(seg.b("confirmed"), st.max_static_sigma_m, st.max_position_sigma_m)
        seg_lost = _line_sigma_at_ends(seg.f("x"), seg.f("P"), seg.f("ends")) > seg_bound
        self._decide(seg, self._segment_view(pose, beams), stamp_ns, seg_lost)
        self._decide(self.cylinders, view.visible[nc:], stamp_ns, lost[nc:])

    def _segment_view(self, pose: PoseSample, beams: Beams | None) -> BoolArray:
        bank = self.segments
        k = len(bank)
        if not k:
            return np.zeros(0, dtype=bool)
        st = self.settings
        a_b, rho_b, lo, hi, sigma = tracker_kernels.lines_to_base(
            bank.f("x"), bank.f("P"), bank.f("ends"), np.ascontiguousarray(pose.pose)
        )
        view = segment_visibility(
            beams, a_b, rho_b, lo, hi, sigma, st.segment_min_beams,
            st.min_range_m, st.max_range_m - st.segment_far_margin_m, st.visibility_margin_m,
        )  # fmt: skip
        return view.visible

    def _decide(
        self, bank: _Bank, visible: BoolArray, stamp_ns: int, lost: BoolArray | None = None
    ) -> None:
        """Misses, confirmation and deletion (module docstring); ``lost``: tracks whose
        position σ exceeds ``max_position_sigma_m``, deleted."""
        if not len(bank):
            return
        st = self.settings
        moving = (
            bank.f("mu_seen") > st.moving_threshold
            if "mu_seen" in bank.a
            else np.zeros(len(bank), dtype=bool)
        )
        drop, newly = tracker_kernels.decide(
            bank.b("updated"), np.ascontiguousarray(visible), bank.i("hits"), bank.i("misses"),
            bank.i("visible_scans"), bank.b("confirmed"), bank.i("last_seen_ns"), moving,
            stamp_ns, st.confirm_hits, min(st.confirm_hits_moving, st.confirm_hits),
            st.confirm_window, st.delete_misses,
            st.delete_misses_moving, st.max_coast_moving_s, st.tentative_timeout_s,
        )  # fmt: skip
        self.counters.tracks_confirmed += int(newly)
        if lost is not None and lost.any():
            self.counters.tracks_deleted_uncertain += int((lost & ~drop).sum())
            drop |= lost
        if drop.any():
            self.counters.tracks_deleted += int(drop.sum())
            bank.keep(~drop)

    # ----------------------------------------------------------------- output
    def tracks(self) -> TrackSet:
        """Every track now (see :class:`TrackSet`), segments, corners, cylinders in turn."""
        st = self.settings
        banks = (self.segments, self.corners, self.cylinders)
        ns, nc, ny = (len(b) for b in banks)
        K = ns + nc + ny
        state = np.zeros((K, 4))
        cov = np.zeros((K, 4, 4))
        cov[:, 2, 2] = cov[:, 3, 3] = st.static_velocity_sigma_m_s**2
        params = np.full((K, 3), np.nan)
        pcov = np.full((K, 3, 3), np.nan)
        extent = np.zeros((K, 4))
        end_seen = np.zeros((K, 2), dtype=np.uint8)
        moving = np.zeros(K)
        if ns:
            seg = self.segments
            tracker_kernels.segment_outputs(
                seg.f("x"), seg.f("P"), seg.f("ends"), seg.b("seen"), SEGMENT_END_SIGMA_M,
                state, cov, params, pcov, extent, end_seen,
            )  # fmt: skip
        if nc:
            i = slice(ns, ns + nc)
            state[i, :2] = params[i, :2] = self.corners.f("x")
            cov[i, :2, :2] = pcov[i, :2, :2] = self.corners.f("P")
        if ny:
            cyl = self.cylinders
            tracker_kernels.cylinder_outputs(
                cyl.f("xm"), cyl.f("Pm"), cyl.f("mu"), cyl.f("r"), cyl.f("r_var"), ns + nc,
                state, cov, params, pcov, extent, moving,
            )  # fmt: skip

        def cat(name: str) -> NDArray[Any]:
            return np.concatenate([b.a[name] for b in banks])

        status, refl = tracker_kernels.common_outputs(
            cat("confirmed"), cat("updated"), cat("refl_sum"), cat("refl_n"),
            STATUS_TENTATIVE, STATUS_COASTING, STATUS_CONFIRMED,
        )  # fmt: skip
        kinds = np.repeat(
            np.array([KIND_SEGMENT, KIND_CORNER, KIND_CYLINDER], dtype=np.uint8), (ns, nc, ny)
        )
        return TrackSet(
            track_id=cat("track_id"), kind=kinds, status=status, state=state,
            covariance=cov, params=params, params_covariance=pcov, extent=extent,
            end_seen=end_seen, reflectivity=refl, moving_probability=moving,
            last_seen_ns=cat("last_seen_ns"), hits=cat("hits"),
            information_bits=cat("bits"),
        )  # fmt: skip


def _mixture_log_dets(bank: _Bank, t: IntArray) -> FloatArray:
    """(r,) ``ln det`` of the position block of the cylinders ``t``'s moment-matched
    covariance (the two models combined as ``tracks/2`` publishes them)."""
    _, P = tracker_kernels.imm_combine(bank.f("xm")[t], bank.f("Pm")[t], bank.f("mu")[t])
    return tracker_kernels.position_log_dets(P, np.arange(t.size))


def _inverse_pose(pose: FloatArray) -> FloatArray:
    """The pose of ``odom`` in ``base_link`` (x, y, yaw) for ``base_link``'s ``pose`` in
    ``odom``: :func:`lines_to_odom` with it takes lines from ``odom`` to ``base_link``."""
    x, y, yaw = (float(v) for v in pose[:3])
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([-(c * x + s * y), s * x - c * y, -yaw])


def _line_sigma_at_ends(lines: FloatArray, P: FloatArray, ends: FloatArray) -> FloatArray:
    """(k,) the larger, over a segment's two ends, of the σ across its line (m): at along
    coordinate ``u`` the line moves across by ``δρ − u·δα``, so ``σ² = P_ρρ − 2u·P_αρ +
    u²·P_αα`` (``lines`` (k, 2) = (α, ρ), ``P`` (k, 2, 2), ``ends`` (k, 2, 2))."""
    if lines.shape[0] == 0:
        return np.zeros(0)
    u = _along(lines, ends)
    var = P[:, 1, 1, None] - 2.0 * u * P[:, 0, 1, None] + u * u * P[:, 0, 0, None]
    return np.asarray(np.sqrt(np.maximum(var, 0.0)).max(axis=1), dtype=np.float64)


def _along(lines: FloatArray, points: FloatArray) -> FloatArray:
    """(k, j) along-line coordinates of points (k, j, 2) on lines (k, 2) = (α, ρ)."""
    s, c = np.sin(lines[:, 0])[:, None], np.cos(lines[:, 0])[:, None]
    return np.asarray(-points[..., 0] * s + points[..., 1] * c, dtype=np.float64)
