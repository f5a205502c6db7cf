"""The free-space profile: how far the vehicle can be sure the way is clear, bearing by bearing.

Two steps, each a pure function of its inputs:

1. :func:`scan_spans` turns one filtered scan (``base_link`` at the scan's reference time)
   into **clear spans**, one per beam whose evidence allows it, and **hits**:

   * a valid sample (flag 0) clears its beam from the centre of scanning to
     ``range − (k·σ + margin)`` and is a hit;
   * a reading beyond the depth of field with a usable signal (flag 3, range above the far
     limit) clears its beam to the far limit less the margin: the beam went further;
   * a mixed or isolated sample (flags 4, 5) or a reading nearer than the depth of field is a
     hit and clears nothing (a phantom range or a thin object: no span can be trusted);
   * a low-signal sample (flag 2) is neither: its range may be noise or a dark surface;
     at the noise level (signal below ``noise_floor_A``) it returned no light at all and
     is judged as a sample with no reading;
   * a sample with no reading (flag 1) is "nothing in range" only when the sensor can vouch
     for it (:func:`vouched_no_return` says when), and then clears from the near end of the
     depth of field (a surface nearer than that images off the detector and returns nothing
     either) to the range within which any surface of ``vouch_min_reflectivity`` seen at up
     to ``vouch_max_view_deg`` from its normal would have returned a signal (at most the far
     limit).

2. :class:`FreeSpaceMap` keeps the spans of recent scans in a local grid in ``odom`` (5 cm
   cells, a square of ``grid_size_m`` re-centred on the vehicle as it moves) and answers the
   profile for any pose: :meth:`FreeSpaceMap.profile`.

**What a cell's "free" means, and why it ages as it does.** When a scan's spans are added,
the cells they cross form its *footprint*. A mover may hide anywhere in the *scanned wedge*
(the cells wholly between the scan's outermost beams, out to the far limit) that is not in
the footprint (past each beam's end, in the gaps of beams that cleared nothing), and at
every hit (what was seen may itself be a mover); never inside the vehicle's own outline.
Each footprint cell gets the distance ``D`` to the nearest such hiding place (a Euclidean
distance transform). A mover whose surface moves at most ``mover_speed_m_s`` cannot reach
the cell before ``(D − edge_m) / mover_speed_m_s`` has passed; ``edge_m`` (one cell plus an
allowance for odometry drift) covers cells only partly observed. The cell stays free until
``scan start + min(max_age_s, (D − edge_m) / mover_speed_m_s)``, the scan's *first* sample
time standing for the whole sweep (the oldest, so the most cautious). A later scan may only
extend that deadline; a hit ends it at once for every cell within ``hit_dilation_m`` (hits
override clears, also within one scan). Free space therefore *shrinks* from what could hide a
mover, at the mover's speed, rather than being dropped at a fixed age; ``max_age_s`` (0.5 s)
drops what remains, and bounds what odometry drift can do to it.

**Flanks: the stated limit.** The space beside the scanned wedge is *not* taken as a hiding
place. It would be the sound choice, but the wedge's apex sits 10 cm behind the vehicle's
front: every cell ahead of the bumper is within a few centimetres of the unscanned space
beside the apex, and no ray from the centre of scanning would ever be known clear (measured:
a fixed forward window then claims nothing at all). So a mover that enters the free space
from outside the scanned wedge within ``max_age_s`` is not guarded against; ``edge_m`` and
the half-step sectors of the profile absorb its first few centimetres. The vehicle's outline
counts as clear, so a mover that walks into the vehicle (a collision) makes every claim
through it false.

**The profile.** From the centre of scanning (``mount_offset_m`` ahead of ``base_link``, on
the pan axis) at the query pose, for each bearing of a fixed grid (``bearing_step_deg``, from
−180° in ``base_link`` axes), the distance along which every grid sample (half a cell apart)
is free, taken as the smallest over three rays at the bearing and half a step either side,
so that the value holds for the whole sector between the neighbouring bearings. The
vehicle's own body counts as free (nothing else can be there), but a bearing known clear
no further than the body's edge is 0: unknown is 0. Never beyond the far limit of the
depth of field.

**Where a sector ends.** A sector of the profile ends at a surface (:meth:`FreeSpaceMap.
end_hits`, the vector's ``free_end_hit``) when a recent hit lies beyond its end within the
distance a hit's own erosion reaches (``edge_m`` plus what a mover covers since the scan,
the dilation and a cell); otherwise it ends where knowledge ends. A controller marks
possible obstacles only at the former: in open space every sector ends somewhere, at no
surface.

**Cost.** A scan's spans (:func:`scan_spans`: its trigonometry still in numpy, to the bit),
its update and a profile run compiled (:mod:`agent.planning.free_space_kernels`), each in one
pass over what it concerns: the samples, the box of cells around the scanned wedge, the
profile's rays up to their first cell not free. The spans took 335 µs a scan in numpy, two
thirds of it in call overhead (:func:`scan_spans_reference`). Measured on the planner stage's
scans: about 0.2 ms per update and 0.04 ms per profile (p50; p99 0.3-0.4 and 0.1 ms), against
0.9-1.6 ms and 0.3-0.6 ms in numpy; the kernels reproduce the numpy formulation to the bit
(the tests compare them on synthetic scans and on the simulator chain's). The end hits,
compiled, about 85 µs with 229 of the 360 sectors lit (4.2 ms in numpy,
:func:`end_hits_reference`), where the profile took 254 µs, on a loaded machine.
:func:`warm_up` loads them, so that the first scan of a process does not.

Frames: REP-103 (x forward, y left, angles counter-clockwise), metres, radians, seconds on
the graph's clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.arrays import BoolArray, FloatArray, shifted, wrap_angle
from agent.compiled import fresh_floats as _fresh
from agent.perception.filtering import SampleFlag
from agent.planning import free_space_kernels as kernels
from agent.sensor.params import SensorParameters

IntArray = NDArray[np.int64]
_RAMP9 = np.arange(0, 9, dtype=np.float64)
_VALID, _NO_READING, _LOW_SNR = (
    int(SampleFlag.VALID),
    int(SampleFlag.NO_READING),
    int(SampleFlag.LOW_SNR),
)
_OUT_OF_RANGE, _MIXED, _ISOLATED = (
    int(SampleFlag.OUT_OF_RANGE),
    int(SampleFlag.MIXED),
    int(SampleFlag.ISOLATED),
)
# The scanned wedge's arguments of the compiled update (FreeSpaceMap._wedge).
_Wedge = tuple[
    float, float, FloatArray, FloatArray, int, tuple[float, float], tuple[float, float],
    tuple[float, float], float,
]  # fmt: skip


@dataclass(frozen=True)
class FreeSpaceSettings:
    """Every constant of the free-space profile, with its reason.

    Spans (:func:`scan_spans`)
    --------------------------
    range_sigmas, range_margin_m
        A valid return clears its beam to ``range − (range_sigmas·σ + range_margin_m)``:
        3σ leaves a Gaussian range error past the return 0.13 % of the time, and 3 cm
        covers the spot's footprint and the calibration's residual (about 1 cm).
    depth_of_field_m
        The sensor's rated interval (0.4, 2.5) m: no claim beyond its far end, and a no-return
        vouches only from its near end (nearer surfaces image off the detector).
    signal_floor_A
        A sample's signal below this is "no signal": 20 noise currents (the filter's SNR
        gate) of the nominal sensor, 0.73 nA.
    noise_floor_A
        A no-reading sample vouches for nothing in range only if its signal is below this,
        i.e. at the noise level: 4·I_n (146 pA), far above the ~9 pA scatter of a noise-only
        sample's sum current, far below any surface in range.
    vouch_min_reflectivity, vouch_max_view_deg
        The dimmest surface a no-return must exclude: reflectivity 0.2 (the darkest
        obstacles of the project's worlds, a dark chair leg) seen up to 84° from its normal
        (cos = 0.1). Eq. 6.10-6.11 give the range within which such a surface returns more
        than ``noise_floor_A``: about 1.8 m at θ = 0 with the nominal S.
    baseline_m
        The detector's viewpoint lies this far to the left of the beam's origin (the
        triangulation baseline, 9.5 cm). An object between a spot and that viewpoint hides
        the spot (a *missing part*) and the beam returns nothing although it hit a surface.
    shadow_margin_deg
        Angular slack on the missing-part test, for pan and sample-timing errors.
    pan_tolerance_deg
        The pan told by the head must agree with the beams' measured headings within this
        for a scan's no-returns to be placed at all.

    Map (:class:`FreeSpaceMap`)
    ---------------------------
    cell_m, grid_size_m
        5 cm cells over an 8 m square: the far limit (2.5 m) plus the mount offset and the
        re-centring slack fit on every side.
    recentre_m
        The grid is re-centred on the vehicle when it has moved this far from the centre.
    hit_dilation_m
        A hit marks every cell within this of it: one cell beyond its own, so a ray can cross
        no corner of a hit's cell unseen.
    edge_m
        Distance inside a footprint below which a cell is never free: one cell (a boundary
        cell is only partly observed) plus 2 cm for odometry drift over ``max_age_s``
        (2 % of 1 m of travel).
    mover_speed_m_s
        The fastest a mover's surface moves (0.8 m/s: the fastest movers of the project's
        scenes). Free space shrinks from its edges at this speed.
    max_age_s
        No cell stays free longer than this after its scan began, whatever its depth (0.5 s:
        five scans). It bounds what the profile does not guard against (movers entering from
        outside the scanned wedge, "flanks" above) and the odometry drift between the scan
        and the query (5 mm at 0.5 m/s and 2 %).
    far_gap_m
        The far profile (:meth:`FreeSpaceMap.profile_far`) starts this far beyond the near
        limit: the first 0.4 m of a no-return's beam are unseen, so a mover may hide there,
        and a cell is free only ``edge_m`` plus what a mover covers between scans (0.8 m/s
        for 0.1 s) away from it: 0.07 + 0.08 m.
    bearing_step_deg, max_profile_m
        The profile's grid of bearings (1°, 360 bearings) and its reach (the far limit).
    body_length_m, body_width_m
        The vehicle's own rectangle, centred on ``base_link``'s origin (0.8 m × 0.6 m, the
        project's platform): nothing else can be where the vehicle is, so its cells count
        as free, in every scan's footprint and in the profile. Without it the footprint of a
        ±20° window would be a thin wedge at the centre of scanning, and the space just
        beside its apex would bound every ray's clearance to a few centimetres.
    """

    range_sigmas: float = 3.0
    range_margin_m: float = 0.03
    depth_of_field_m: tuple[float, float] = (0.4, 2.5)
    signal_floor_A: float = 20 * 36.5e-12
    noise_floor_A: float = 4 * 36.5e-12
    vouch_min_reflectivity: float = 0.2
    vouch_max_view_deg: float = 84.26  # cos = 0.1
    signal_constant_Am2: float = 2.59e-8
    baseline_m: float = 0.095
    shadow_margin_deg: float = 1.0
    pan_tolerance_deg: float = 1.0
    cell_m: float = 0.05
    grid_size_m: float = 8.0
    recentre_m: float = 0.5
    hit_dilation_m: float = 0.05
    edge_m: float = 0.07
    mover_speed_m_s: float = 0.8
    max_age_s: float = 0.5
    far_gap_m: float = 0.15
    bearing_step_deg: float = 1.0
    max_profile_m: float = 2.5
    body_length_m: float = 0.8
    body_width_m: float = 0.6

    def __post_init__(self) -> None:
        positive = (
            "range_margin_m", "signal_floor_A", "noise_floor_A", "vouch_min_reflectivity",
            "signal_constant_Am2", "baseline_m", "cell_m", "grid_size_m", "recentre_m",
            "edge_m", "mover_speed_m_s", "max_age_s", "far_gap_m", "bearing_step_deg",
            "max_profile_m",
        )  # fmt: skip
        for name in ("body_length_m", "body_width_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"free-space setting {name} must be >= 0, got {value}")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"free-space setting {name} must be positive, got {value}")
        for name in ("range_sigmas", "shadow_margin_deg", "pan_tolerance_deg", "hit_dilation_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"free-space setting {name} must be >= 0, got {value}")
        near, far = self.depth_of_field_m
        if not 0 < near < far:
            raise ValueError(
                f"depth_of_field_m must be 0 < near < far, got {self.depth_of_field_m}"
            )
        if not 0 < self.vouch_max_view_deg < 90:
            raise ValueError(
                f"vouch_max_view_deg must lie in (0, 90), got {self.vouch_max_view_deg}"
            )
        if (360.0 / self.bearing_step_deg) % 1 > 1e-9:
            raise ValueError(f"bearing_step_deg must divide 360, got {self.bearing_step_deg}")
        if self.grid_size_m < 2 * (self.max_profile_m + self.recentre_m + 0.5):
            raise ValueError(
                f"grid_size_m {self.grid_size_m} cannot hold the profile's reach "
                f"{self.max_profile_m} m and the re-centring slack {self.recentre_m} m"
            )

    @classmethod
    def for_sensor(cls, sensor: SensorParameters, **overrides: float) -> FreeSpaceSettings:
        """Settings whose sensor constants (depth of field, S, I_n, baseline) are ``sensor``'s."""
        base = {
            "depth_of_field_m": sensor.depth_of_field_m,
            "signal_floor_A": 20 * sensor.noise_current_A,
            "noise_floor_A": 4 * sensor.noise_current_A,
            "signal_constant_Am2": sensor.signal_constant_Am2,
            "baseline_m": sensor.baseline_m,
            "max_profile_m": sensor.depth_of_field_m[1],
        }
        return cls(**{**base, **overrides})  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class ClearSpans:
    """One scan's evidence in ``base_link`` at the scan's reference time.

    ``origin_xy`` (n, 2) m and ``heading_rad`` (n,) of each beam; the clear interval
    ``[start_m, end_m]`` along it (none where ``end_m <= start_m``); ``hits_xy`` (h, 2) m,
    points where something was seen. ``vouched`` (n,) marks no-return beams taken as
    nothing in range; ``heading_known`` (n,) the beams whose heading is known (a reading,
    or told, by the filter or a steady pan): the scanned wedge is drawn through them.
    """

    origin_xy: FloatArray
    heading_rad: FloatArray
    start_m: FloatArray
    end_m: FloatArray
    hits_xy: FloatArray
    vouched: BoolArray
    heading_known: BoolArray

    @property
    def spans(self) -> int:
        return int(np.count_nonzero(self.end_m > self.start_m))


def vouch_range_m(scan_angle_rad: FloatArray, settings: FreeSpaceSettings) -> FloatArray:
    """Range (m) within which a surface of the dimmest kind would return above the noise floor.

    Eq. 6.10-6.11 solved for r: ``r = sqrt(ρ_min·S·cos(view_max)·cos θ / noise_floor)``,
    capped at the far limit of the depth of field.
    """
    s = settings
    cos_view = math.cos(math.radians(s.vouch_max_view_deg))
    r2 = (
        s.vouch_min_reflectivity * s.signal_constant_Am2 * cos_view * np.cos(scan_angle_rad)
    ) / s.noise_floor_A
    return np.minimum(np.sqrt(np.maximum(r2, 0.0)), s.depth_of_field_m[1])


def scan_dark(
    beam_rad: FloatArray,
    range_m: FloatArray,
    flag: NDArray[np.uint8],
    intensity_A: FloatArray,
    window_rad: tuple[float, float],
    settings: FreeSpaceSettings,
    bearings_rad: FloatArray,
) -> FloatArray:
    """How far one scan returned no light, per sector of the profile's bearing grid.

    ``beam_rad`` (n,): each sample's bearing from the centre of scanning, ``base_link`` axes
    at the scan's stamp; ``window_rad``: its outermost beams (low, high). A sample returned
    no light when it has no reading, or a low-signal one, at the noise level (signal below
    ``noise_floor_A``, as :func:`scan_spans` judges a no-return); any other returned light
    at its range (a valid reading, a mixed, isolated, too-near or too-far one; at 0 when its
    range is not finite). ``bearings_rad`` (b,): the profile's grid, from −π in equal steps
    (:attr:`FreeSpaceMap.bearings_rad`). Returns (b,): in each sector whose bearing lies in
    the window, the range of the nearest sample that returned light, else the far limit;
    0 outside the window. Unlike the profile, which also reads 0 where light came back and
    left no clear span, this 0 or a short range never means silence (the vector's
    ``scan_dark_m``)."""
    n_bearings = bearings_rad.size
    step = 2.0 * math.pi / n_bearings
    low, high = window_rad
    inside = (bearings_rad >= low) & (bearings_rad <= high)
    dark = np.where(inside, settings.depth_of_field_m[1], 0.0)
    with np.errstate(invalid="ignore"):
        silent = ((flag == _NO_READING) | (flag == _LOW_SNR)) & (
            intensity_A < settings.noise_floor_A
        )
    lit = ~silent & np.isfinite(beam_rad)
    if lit.any():
        reach = np.where(np.isfinite(range_m[lit]), np.clip(range_m[lit], 0.0, None), 0.0)
        sector = np.floor((beam_rad[lit] + math.pi) / step + 0.5).astype(np.int64) % n_bearings
        np.minimum.at(dark, sector, reach)
    return np.asarray(dark, dtype=np.float64)


def vouched_no_return(
    heading_rad: FloatArray,
    range_m: FloatArray,
    candidate: BoolArray,
    occluder: BoolArray,
    settings: FreeSpaceSettings,
) -> BoolArray:
    """Which no-return beams can be taken as "nothing in range" (the sensor can vouch for it).

    A beam that hit a surface returns nothing when the path from the spot to the detector,
    whose viewpoint is a baseline ``d`` to the *left* (counter-clockwise) of the beam's
    origin, is blocked: a *missing part*. The blocking object lies in the thin triangle
    spot-origin-viewpoint, so at a range ρ it is within ``d/ρ`` rad to the left of the beam.
    A candidate is refused when

    * any ``occluder`` beam (one that saw something, at ``range_m``) lies to its left within
      ``d/range + margin``: that object may hide the candidate's spot;
    * the scan does not reach ``d/near + margin`` to its left (``near`` the depth of field's
      near end): an object there, unscanned, may hide it. Objects nearer than ``near`` are
      invisible to the sensor; they are the profile's stated blind spot (docs).

    Parameters
    ----------
    heading_rad
        (n,) beam headings, ``base_link`` at the reference time; the scan's beams in any
        order, all from one sweep (so within 40° of each other).
    range_m
        (n,) the range each occluder beam saw (NaN elsewhere); an occluder with NaN range is
        taken at the near limit (it returned light but no reading: something very close).
    candidate, occluder
        (n,) which beams are no-returns to judge, and which saw something.
    """
    s = settings
    near = s.depth_of_field_m[0]
    margin = math.radians(s.shadow_margin_deg)
    ref = heading_rad[0] if heading_rad.size else 0.0
    rel = wrap_angle(heading_rad - ref)  # unwrapped around the sweep: it spans 40° at most
    vouched = candidate.copy()
    if not np.any(candidate):
        return vouched
    # Nothing scanned far enough to the left of it.
    vouched &= rel + s.baseline_m / near + margin <= rel.max()
    # Each occluder shades the interval [its heading − d/r − margin, its heading + margin].
    occ = np.flatnonzero(occluder)
    if occ.size:
        r = np.where(np.isfinite(range_m[occ]), np.maximum(range_m[occ], near), near)
        high = rel[occ] + margin
        low = rel[occ] - s.baseline_m / r - margin
        order = np.argsort(low)
        low, reach = low[order], np.maximum.accumulate(high[order])
        k = np.flatnonzero(vouched)
        before = np.searchsorted(low, rel[k], side="right")  # intervals starting at or before
        shaded = (before > 0) & (reach[np.maximum(before - 1, 0)] >= rel[k])
        vouched[k[shaded]] = False
    return vouched


def told_headings(
    scan_angle_rad: FloatArray,
    pan_rad: float | None,
    yaw_rate_rad_s: float,
    sample_period_s: float,
    beam_rad: FloatArray | None,
) -> FloatArray | None:
    """Each beam's direction as the filter tells it (``beam_rad``), else as the head's steady
    pan does, ``pan + θ − ω·(t_ref − t_k)`` (samples ``sample_period_s`` apart, the last at
    ``t_ref``), (n,); ``None`` when neither does (:func:`scan_spans`)."""
    if beam_rad is not None:
        return np.array(beam_rad, dtype=np.float64)
    if pan_rad is None:
        return None
    n = scan_angle_rad.size
    age = (n - 1 - np.arange(n)) * sample_period_s
    return np.asarray(pan_rad + scan_angle_rad - yaw_rate_rad_s * age, dtype=np.float64)


def scan_spans(
    points_xy: FloatArray,
    origin_xy: FloatArray,
    scan_angle_rad: FloatArray,
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity_A: FloatArray,
    flag: NDArray[np.uint8],
    settings: FreeSpaceSettings,
    pan_rad: float | None = None,
    yaw_rate_rad_s: float = 0.0,
    sample_period_s: float = 1.0 / 2560.0,
    beam_rad: FloatArray | None = None,
) -> ClearSpans:
    """One filtered scan's clear spans and hits (module docstring, step 1).

    Parameters
    ----------
    points_xy, origin_xy, scan_angle_rad, range_m, sigma_m, intensity_A, flag
        The filtered scan's per-sample arrays (``base_link`` at the scan's reference time,
        its last sample), as in ``filtered_scan/1``.
    beam_rad
        Each beam's direction (n,), ``base_link`` at the reference time, as the filter tells
        it (``filtered_scan/1``'s ``beam_rad``: from the head's pan at each sample, so also
        while the head slewed); where given, a no-return's beam goes there.
    pan_rad
        Without ``beam_rad``: the head's pan during the sweep, if it was steady (settled);
        ``None`` (and no ``beam_rad``): unknown, and then no-returns are never vouched for
        (their headings are unknown).
    yaw_rate_rad_s
        With ``pan_rad``: the vehicle's yaw rate: a no-return's heading at the reference
        time is ``pan + θ − ω·(t_ref − t_k)``, the samples ``sample_period_s`` apart, the
        last at ``t_ref``.
    """
    s = settings
    near, far = s.depth_of_field_m
    has_point, d = kernels.beam_offsets(_fresh(points_xy), _fresh(origin_xy), _fresh(range_m))
    heading = np.arctan2(d[:, 1], d[:, 0])
    told = told_headings(scan_angle_rad, pan_rad, yaw_rate_rad_s, sample_period_s, beam_rad)
    constants = (
        float(near), float(far), float(s.range_sigmas), float(s.range_margin_m),
        float(s.signal_floor_A), float(s.noise_floor_A), math.radians(s.pan_tolerance_deg),
        s.baseline_m / near, math.radians(s.shadow_margin_deg), float(s.baseline_m),
    )  # fmt: skip
    start, end, hit, vouched, known = kernels.scan_evidence(
        heading, has_point, _fresh(range_m), _fresh(sigma_m), np.array(flag, dtype=np.uint8),
        _fresh(intensity_A), told is not None, heading if told is None else told, constants,
    )  # fmt: skip
    if vouched.any():
        end[vouched] = vouch_range_m(scan_angle_rad[vouched], s) - s.range_margin_m
    return ClearSpans(
        origin_xy=np.asarray(origin_xy, dtype=np.float64),
        heading_rad=heading,
        start_m=start,
        end_m=end,
        hits_xy=np.asarray(points_xy[hit], dtype=np.float64),
        vouched=vouched,
        heading_known=known,
    )


def scan_spans_reference(
    points_xy: FloatArray,
    origin_xy: FloatArray,
    scan_angle_rad: FloatArray,
    range_m: FloatArray,
    sigma_m: FloatArray,
    intensity_A: FloatArray,
    flag: NDArray[np.uint8],
    settings: FreeSpaceSettings,
    pan_rad: float | None = None,
    yaw_rate_rad_s: float = 0.0,
    sample_period_s: float = 1.0 / 2560.0,
    beam_rad: FloatArray | None = None,
) -> ClearSpans:
    """:func:`scan_spans` in numpy, as it was before its loops were compiled (measured on
    the planner stage's scans: 335 µs a scan, two thirds of it in call overhead): the
    reference the tests compare the kernels with."""
    s = settings
    n = int(flag.size)
    near, far = s.depth_of_field_m
    has_point = np.isfinite(points_xy).all(axis=1) & np.isfinite(range_m)
    d = np.where(has_point[:, None], points_xy - origin_xy, 0.0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    start = np.zeros(n)
    end = np.zeros(n)

    valid = (flag == _VALID) & has_point
    sig = np.where(np.isfinite(sigma_m), sigma_m, np.inf)
    end[valid] = np.minimum(
        range_m[valid] - (s.range_sigmas * sig[valid] + s.range_margin_m), far - s.range_margin_m
    )
    beyond = (
        (flag == _OUT_OF_RANGE) & has_point & (range_m > far) & (intensity_A >= s.signal_floor_A)
    )
    end[beyond] = far - s.range_margin_m
    hit = has_point & (
        valid
        | (flag == _MIXED)
        | (flag == _ISOLATED)
        | ((flag == _OUT_OF_RANGE) & (range_m < near))
    )

    no_return = (flag == _NO_READING) & ~has_point
    # A low-SNR sample at the noise level returned no light either: its "position" is the
    # ratio of two noise currents (measured in open space: about 7 % of the beams, at
    # random ranges of 0.4-1.1 m). Taken as an occluder, each such sample shaded up to 14°
    # of no-returns beside it, and a window facing open space vouched for almost nothing.
    candidate = (intensity_A < s.noise_floor_A) & (no_return | (flag == _LOW_SNR))
    vouched = np.zeros(n, dtype=bool)
    known = has_point.copy()
    model = told_headings(scan_angle_rad, pan_rad, yaw_rate_rad_s, sample_period_s, beam_rad)
    if model is not None and n and np.any(candidate):
        # The told headings must agree with the headings the returns measured.
        agree = not np.any(has_point) or float(
            np.median(np.abs(wrap_angle(heading[has_point] - model[has_point])))
        ) <= math.radians(s.pan_tolerance_deg)
        if agree:
            heading = np.where(has_point & ~candidate, heading, wrap_angle(model))
            known[:] = True
            # Whatever returned light saw something: a reading (any flag) or a no-reading
            # with signal above the noise floor (a surface imaged off the detector).
            occluder = (has_point | no_return) & ~candidate
            vouched = vouched_no_return(heading, range_m, candidate, occluder, s)
            start[vouched] = near
            end[vouched] = vouch_range_m(scan_angle_rad[vouched], s) - s.range_margin_m
    return ClearSpans(
        origin_xy=np.asarray(origin_xy, dtype=np.float64),
        heading_rad=heading,
        start_m=start,
        end_m=end,
        hits_xy=np.asarray(points_xy[hit], dtype=np.float64),
        vouched=vouched,
        heading_known=known,
    )


def warm_up() -> None:
    """Load the map's compiled kernels (compiling them on the first use on a machine)."""
    kernels.warm_up()


def end_hits_reference(
    fmap: FreeSpaceMap, pose: tuple[float, float, float], now_s: float, ranges: FloatArray
) -> NDArray[np.uint8]:
    """:meth:`FreeSpaceMap.end_hits` in numpy, every step of every ray at once: the tests'
    reference for its kernel."""
    s = fmap.settings
    b = fmap.bearings_rad.size
    out = np.zeros(b, dtype=np.uint8)
    x, y, yaw = pose
    c, si = math.cos(yaw), math.sin(yaw)
    centre = np.array([x + fmap.mount_offset_m * c, y + fmap.mount_offset_m * si])
    lit = np.flatnonzero(np.asarray(ranges) > 0.0)
    if not lit.size:
        return out
    dirs = fmap._sub_dirs @ np.array([[c, -si], [si, c]]).T
    rays = np.stack([(2 * lit - 1) % (2 * b), 2 * lit, 2 * lit + 1], axis=1)  # (l, 3)
    beyond = fmap._end_steps
    reach = ranges[lit][:, None, None] + beyond  # (l, 1, m)
    points = centre + reach[..., None] * dirs[rays][:, :, None, :]  # (l, 3, m, 2)
    cells = np.floor((points - fmap.origin) / s.cell_m).astype(np.int64)
    inside = ((cells >= 0) & (cells < fmap.size)).all(axis=-1)
    # A ray stops at the grid's edge: nothing past its first step outside counts.
    inside = np.cumprod(inside, axis=-1).astype(bool)
    at = np.full(inside.shape, -np.inf)
    at[inside] = fmap.hit_at[cells[inside][:, 0], cells[inside][:, 1]]
    allowed = (
        s.edge_m + s.hit_dilation_m + s.cell_m + s.mover_speed_m_s * np.maximum(now_s - at, 0.0)
    )
    surface = (at >= now_s - s.max_age_s) & (beyond <= allowed)
    out[lit] = surface.any(axis=(1, 2))
    return out


def _disk_offsets(radius_cells: float) -> IntArray:
    """(m, 2) integer cell offsets within ``radius_cells`` (at least the cell itself)."""
    r = math.ceil(radius_cells)
    di, dj = np.mgrid[-r : r + 1, -r : r + 1]
    inside = di * di + dj * dj <= radius_cells * radius_cells + 1e-9
    return np.stack([di[inside], dj[inside]], axis=1).astype(np.int64)


class FreeSpaceMap:
    """Recent scans' clear spans in a local ``odom`` grid; the profile for any pose.

    See the module docstring for what a free cell means. Scans must come in time order: an
    older scan than the newest added is refused (``add`` returns False).

    Parameters
    ----------
    settings
        The constants (:class:`FreeSpaceSettings`).
    mount_offset_m
        The centre of scanning (the pan axis) ahead of ``base_link``'s origin.
    """

    def __init__(self, settings: FreeSpaceSettings | None = None, mount_offset_m: float = 0.30):
        self.settings = s = settings if settings is not None else FreeSpaceSettings()
        self.mount_offset_m = mount_offset_m
        self.size = round(s.grid_size_m / s.cell_m)
        # Each cell's deadline: free until then (s, graph clock); -inf: not known free.
        self.free_until = np.full((self.size, self.size), -np.inf)
        # Each cell's newest hit (a sample that returned from it, dilated as for the
        # deadlines), as its scan's start: whether a sector ends at a surface (end_hits).
        self.hit_at = np.full((self.size, self.size), -np.inf)
        reach = s.edge_m + s.hit_dilation_m + s.cell_m + s.mover_speed_m_s * s.max_age_s
        self._end_steps = np.arange(0.0, reach + 1e-9, 0.5 * s.cell_m)
        self.origin = np.zeros(2)  # odom coordinates of cell (0, 0)'s lower corner
        self._centred = False
        self.newest_scan_s = -math.inf
        self._hit_offsets = _disk_offsets(s.hit_dilation_m / s.cell_m)
        # The box of a scan's update reaches this many cells beyond the wedge and the
        # footprint: a deadline depends on nothing farther (one cell beyond the distance at
        # which every deadline is max_age_s).
        self._pad = math.ceil((s.mover_speed_m_s * s.max_age_s + s.edge_m) / s.cell_m) + 1
        empty = np.zeros(0)
        self._no_wedge: _Wedge = (
            0.0, 0.0, empty, empty, 0, (1.0, 0.0), (1.0, 0.0), (1.0, 0.0), 0.0
        )  # fmt: skip
        self._steps = np.arange(0.0, s.max_profile_m + 1e-9, 0.5 * s.cell_m)
        n_bearings = round(360.0 / s.bearing_step_deg)
        self.bearings_rad: FloatArray = np.asarray(
            -np.pi + np.arange(n_bearings) * math.radians(s.bearing_step_deg), dtype=np.float64
        )
        sub = -np.pi + np.arange(2 * n_bearings) * 0.5 * math.radians(s.bearing_step_deg)
        self._sub_dirs = np.stack([np.cos(sub), np.sin(sub)], axis=1)  # (2b, 2)
        # The vehicle's body: lattice points (base_link) at a quarter cell, for rasterising it
        # into a footprint, and which profile samples lie inside it (pose-independent).
        half_l, half_w = 0.5 * s.body_length_m, 0.5 * s.body_width_m
        q = 0.25 * s.cell_m
        bx = np.arange(-half_l, half_l + 1e-9, q) if half_l > 0 else np.zeros(0)
        by = np.arange(-half_w, half_w + 1e-9, q) if half_w > 0 else np.zeros(0)
        gx, gy = np.meshgrid(bx, by, indexing="ij")
        self._body_points = np.stack([gx.ravel(), gy.ravel()], axis=1)
        ray_x = mount_offset_m + self._steps[None, :] * self._sub_dirs[:, 0, None]
        ray_y = self._steps[None, :] * self._sub_dirs[:, 1, None]
        in_body = (np.abs(ray_x) <= half_l) & (np.abs(ray_y) <= half_w)  # (2b, m)
        # The first step of each ray outside the body (the body is convex and holds the
        # centre of scanning: inside up to there, outside beyond).
        self._exit: IntArray = np.where(
            in_body.all(axis=1), self._steps.size, np.argmin(in_body, axis=1)
        ).astype(np.int64)
        # The first step at or beyond where the far profile starts (:meth:`profile_far`).
        self.far_from_m = s.depth_of_field_m[0] + s.far_gap_m
        first = int(np.searchsorted(self._steps, self.far_from_m - 1e-9))
        self._far_exit: IntArray = np.maximum(self._exit, first).astype(np.int64)

    # -------------------------------------------------------------------------------- grid
    def recentre(self, x_m: float, y_m: float) -> None:
        """Centre the grid near (x, y) (odom) if it is ``recentre_m`` or more away, keeping
        the cells that stay inside."""
        s = self.settings
        half = 0.5 * self.size * s.cell_m
        if self._centred:
            centre = self.origin + half
            if max(abs(x_m - centre[0]), abs(y_m - centre[1])) < s.recentre_m:
                return
        new_origin = np.floor((np.array([x_m, y_m]) - half) / s.cell_m) * s.cell_m
        if not self._centred:
            self.origin, self._centred = new_origin, True
            return
        shift = np.round((new_origin - self.origin) / s.cell_m).astype(np.int64)
        self.free_until = shifted(self.free_until, int(shift[0]), int(shift[1]))
        self.hit_at = shifted(self.hit_at, int(shift[0]), int(shift[1]))
        self.origin = new_origin

    # -------------------------------------------------------------------------------- scans
    def add(
        self,
        spans: ClearSpans,
        pose: tuple[float, float, float],
        scan_start_s: float,
        scan_end_s: float,
    ) -> bool:
        """Add one scan's spans, given in ``base_link`` at ``pose`` (x, y, yaw in ``odom``,
        the vehicle's pose at the scan's reference time ``scan_end_s``).

        Its footprint: the cells the spans cross, sampled every 0.7 cell along each span, its
        end included. A cell a beam only grazes may be missed: the footprint can only come
        out smaller, never larger (neighbouring beams, 0.16° apart, fill in). Its hits mark
        every cell within ``hit_dilation_m``. The deadlines (module docstring) are worked in
        the box of cells that holds the scanned wedge and the footprint, padded by the
        farthest a deadline looks (``edge_m + mover_speed_m_s · max_age_s``), by
        :func:`agent.planning.free_space_kernels.add_scan`.

        Returns False (and changes nothing) for a scan older than the newest added, or at a
        pose or times that are not finite.
        """
        x, y, yaw = float(pose[0]), float(pose[1]), float(pose[2])
        if not all(map(math.isfinite, (x, y, yaw, scan_start_s, scan_end_s))):
            return False
        if scan_end_s < self.newest_scan_s:
            return False
        self.newest_scan_s = scan_end_s
        self.recentre(x, y)
        s = self.settings
        c, si = math.cos(yaw), math.sin(yaw)
        turn = np.array([[c, -si], [si, c]]).T
        # Points turned into odom axes here and placed at (x, y) by the kernel: the beams'
        # origins, the hits, the vehicle's own lattice (its cells hide nothing).
        beam_xy = _fresh(spans.origin_xy @ turn)
        heading = spans.heading_rad + yaw
        known = np.flatnonzero(spans.heading_known)
        if known.size:
            k = known[-1]
            wedge = self._wedge(beam_xy[k, 0] + x, beam_xy[k, 1] + y, heading[known])
        else:
            wedge = self._no_wedge
        kernels.add_scan(
            self.free_until, float(self.origin[0]), float(self.origin[1]), float(s.cell_m), x,
            y, beam_xy, _fresh(np.cos(heading)), _fresh(np.sin(heading)), _fresh(spans.start_m),
            _fresh(spans.end_m), 0.7 * s.cell_m, _fresh(spans.hits_xy.reshape(-1, 2) @ turn),
            self._hit_offsets, bool(known.size), _fresh(self._body_points @ turn), *wedge,
            float(s.edge_m), float(s.mover_speed_m_s), float(s.max_age_s), float(scan_start_s),
        )  # fmt: skip
        self._mark_hits(spans.hits_xy.reshape(-1, 2) @ turn + np.array([x, y]), scan_start_s)
        return True

    def _mark_hits(self, hits_xy: FloatArray, at_s: float) -> None:
        """Stamp ``at_s`` into :attr:`hit_at` for every cell within ``hit_dilation_m`` of a
        hit (``odom``), as the update ends those cells' deadlines."""
        if not hits_xy.size:
            return
        with np.errstate(over="ignore", invalid="ignore"):
            where = np.floor((hits_xy - self.origin) / self.settings.cell_m)
        # Dilated and bounded in floating point; only cells on the grid become integers (a
        # float that is not finite, or beyond int64, has none: a fuzzed pose of 1e306 m).
        cells = (where[:, None, :] + self._hit_offsets[None, :, :]).reshape(-1, 2)
        inside = ((cells >= 0) & (cells < self.size)).all(axis=1)
        on_grid = cells[inside].astype(np.int64)
        self.hit_at[on_grid[:, 0], on_grid[:, 1]] = at_s

    def _wedge(self, centre_x: float, centre_y: float, headings: FloatArray) -> _Wedge:
        """The scanned wedge, as :func:`agent.planning.free_space_kernels.deepen` takes it:
        from the centre of scanning ``(centre_x, centre_y)`` (``odom``), between the
        outermost ``headings`` (``odom``, rad), out to the far limit plus ``edge_m``."""
        s = self.settings
        far = s.depth_of_field_m[1] + s.edge_m
        # The mean direction (np.add.reduce / n is np.mean's own sum and division).
        n = headings.size
        mid = float(
            np.arctan2(np.add.reduce(np.sin(headings)) / n, np.add.reduce(np.cos(headings)) / n)
        )
        rel = wrap_angle(headings - mid)
        lo, hi = float(rel.min()), float(rel.max())
        # np.linspace(lo, hi, 9)'s own arithmetic (ramp · step + lo, the last point hi)
        # without its 25 µs of argument handling.
        step = (hi - lo) / 8
        ramp = _RAMP9 * step if step != 0 else _RAMP9 / 8 * (hi - lo)
        ramp += lo
        ramp[-1] = hi
        arc = mid + ramp
        rim_x, rim_y = centre_x + far * np.cos(arc), centre_y + far * np.sin(arc)
        a_lo, a_hi = mid + lo, mid + hi
        return (
            float(centre_x), float(centre_y), _fresh(rim_x), _fresh(rim_y), self._pad,
            (math.cos(a_lo), math.sin(a_lo)), (math.cos(a_hi), math.sin(a_hi)),
            (math.cos(mid), math.sin(mid)), float(far),
        )  # fmt: skip

    # ------------------------------------------------------------------------------ profile
    def free_mask(self, now_s: float) -> BoolArray:
        """(size, size) cells known free at ``now_s``."""
        return np.asarray(self.free_until >= now_s)

    def profile(
        self, pose: tuple[float, float, float], now_s: float
    ) -> tuple[FloatArray, FloatArray]:
        """The free-space profile at ``pose`` (x, y, yaw of ``base_link`` in ``odom``) and time.

        Returns
        -------
        bearings_rad : (b,) from −π in steps of ``bearing_step_deg``, ``base_link`` axes.
        free_range_m : (b,) distance from the centre of scanning known clear over the sector
            of half a step either side of each bearing; 0 where unknown.
        """
        x, y, yaw = pose
        c, si = math.cos(yaw), math.sin(yaw)
        centre = np.array([x + self.mount_offset_m * c, y + self.mount_offset_m * si])
        if not (self._centred and np.isfinite(centre).all() and math.isfinite(now_s)):
            return self.bearings_rad.copy(), np.zeros(self.bearings_rad.size)
        rot = np.array([[c, -si], [si, c]])
        dirs = self._sub_dirs @ rot.T  # (2b, 2) in odom
        # March outwards from where each ray leaves the body to its first cell not free;
        # known clear only as far as the body is no knowledge: 0 (unknown). Bearing k is
        # sub-ray 2k; its sector reaches sub-rays 2k - 1 and 2k + 1.
        ranges = kernels.profile_ranges(
            self.free_until, float(now_s), float(centre[0] - self.origin[0]),
            float(centre[1] - self.origin[1]), _fresh(dirs[:, 0]), _fresh(dirs[:, 1]),
            self._steps, self._exit, float(self.settings.cell_m),
        )  # fmt: skip
        return self.bearings_rad.copy(), np.asarray(ranges, dtype=np.float64)

    def end_hits(
        self, pose: tuple[float, float, float], now_s: float, ranges: FloatArray
    ) -> NDArray[np.uint8]:
        """For each bearing of :meth:`profile` (``ranges`` its result at ``pose`` and
        ``now_s``): 1 where the sector's clear range ends at a surface the scans hit, 0
        where it ends where knowledge ends (the scans' reach, a deadline run out, a gap
        between beams) or is 0.

        A hit ends free space short of itself: the cells within ``edge_m`` plus what a
        mover covers since the scan began (``mover_speed_m_s``) of a hit are not free (it
        may be a mover), and the hit marks ``hit_dilation_m`` about it. So an end is at a
        surface when, along one of the sector's three rays, a hit no older than
        ``max_age_s`` lies beyond it within that distance plus a cell. In open space the
        sectors end wherever the recent scans stopped vouching; only an end at a hit can be
        an obstacle not yet tracked.
        """
        s = self.settings
        x, y, yaw = pose
        c, si = math.cos(yaw), math.sin(yaw)
        centre = np.array([x + self.mount_offset_m * c, y + self.mount_offset_m * si])
        if not (self._centred and np.isfinite(centre).all() and math.isfinite(now_s)):
            return np.zeros(self.bearings_rad.size, dtype=np.uint8)
        dirs = self._sub_dirs @ np.array([[c, -si], [si, c]]).T  # (2b, 2) odom
        return np.asarray(
            kernels.end_hits(
                self.hit_at, float(now_s), float(centre[0] - self.origin[0]),
                float(centre[1] - self.origin[1]), _fresh(dirs[:, 0]), _fresh(dirs[:, 1]),
                _fresh(ranges), self._end_steps, s.edge_m + s.hit_dilation_m + s.cell_m,
                float(s.mover_speed_m_s), float(s.max_age_s), float(s.cell_m),
            ),
            dtype=np.uint8,
        )  # fmt: skip

    def profile_far(self, pose: tuple[float, float, float], now_s: float) -> FloatArray:
        """The far profile: for each bearing of :meth:`profile`, the distance from the
        centre of scanning such that the sector from :attr:`far_from_m` (the near end of
        the depth of field plus ``far_gap_m``: 0.55 m) out to it is known clear; 0 where
        unknown.

        A no-return clears its beam only from the near end (a surface nearer images off the
        detector), so while nothing within range returns light, :meth:`profile` stays at 0
        (the first 0.4 m are never seen) although the space beyond is seen clear scan after
        scan: this profile says so, and the vehicle may know the near part from its own
        memory of what it saw from further back.
        """
        x, y, yaw = pose
        c, si = math.cos(yaw), math.sin(yaw)
        centre = np.array([x + self.mount_offset_m * c, y + self.mount_offset_m * si])
        if not (self._centred and np.isfinite(centre).all() and math.isfinite(now_s)):
            return np.zeros(self.bearings_rad.size)
        dirs = self._sub_dirs @ np.array([[c, -si], [si, c]]).T
        ranges = kernels.profile_ranges(
            self.free_until, float(now_s), float(centre[0] - self.origin[0]),
            float(centre[1] - self.origin[1]), _fresh(dirs[:, 0]), _fresh(dirs[:, 1]),
            self._steps, self._far_exit, float(self.settings.cell_m),
        )  # fmt: skip
        return np.asarray(ranges, dtype=np.float64)
