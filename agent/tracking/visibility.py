"""What a scan could have seen: its beams, the tracks it should have seen, and which ends of a
segment it saw end.

A scan's beams (:class:`Beams`) come from the filtered scan in ``base_link`` at its reference
time: each sample's centre of scanning (``origin_xy``), its heading, and what it measured.
The heading of a valid sample is the direction from its origin to its point; the pan and the
vehicle's turning during the sweep are in it. For the samples without a point, the offset
between heading and scan angle (the pan plus the turn so far) is interpolated from the valid
neighbours over the sample index: the head pans and the vehicle turns smoothly within 0.1 s.

What each beam says about the space along it (``seen_m``):

* a valid sample (flag 0): clear up to its range, something there;
* no reading (flag 1), or out of range beyond the far limit (flag 3): nothing in range, clear
  to ``max_range_m`` (a reading nearer than ``min_range_m`` is something that near);
* low signal, mixed or isolated samples (flags 2, 4, 5): unknown (NaN); such a beam is no
  evidence either way.

A track is **expected visible** when at least ``min_beams`` usable beams pass within its
angular footprint, with the track's near surface inside the range limits and the beam's
``seen_m`` not shorter than that distance minus a margin (3σ of the track along the beam plus
5 cm). Beams within the footprint that saw something clearly nearer mean the track is
**occluded**; beams outside the window or range mean it is **out of view**: neither is a miss.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray
from agent.tracking import visibility_kernels

FLAG_VALID, FLAG_NO_READING, FLAG_OUT_OF_RANGE = 0, 1, 3


@dataclass(frozen=True)
class Beams:
    """One scan's usable beams in ``base_link`` at the scan's reference time.

    origin_xy : (n, 2) m, centre of scanning; heading_rad : (n,); seen_m : (n,) the distance
    clear along the beam (module docstring); hit : (n,) bool, the beam saw a surface at
    ``seen_m`` (false: nothing in range); cos_h, sin_h : (n,) of the heading.
    """

    origin_xy: FloatArray
    heading_rad: FloatArray
    seen_m: FloatArray
    hit: NDArray[np.bool_]
    cos_h: FloatArray
    sin_h: FloatArray

    @property
    def count(self) -> int:
        return int(self.heading_rad.size)


def scan_beams(
    points_xy: FloatArray,
    origin_xy: FloatArray,
    scan_angle_rad: FloatArray,
    range_m: FloatArray,
    flag: NDArray[np.uint8],
    min_range_m: float,
    max_range_m: float,
) -> Beams | None:
    """The beams of a filtered scan (module docstring); None when no sample has a point (the
    head's direction cannot then be told: the scan is taken to have seen nothing)."""
    heading, seen, hit, usable, valid = visibility_kernels.scan_beams(
        np.asarray(points_xy, dtype=np.float64), np.asarray(origin_xy, dtype=np.float64),
        np.asarray(scan_angle_rad, dtype=np.float64), np.asarray(range_m, dtype=np.float64),
        np.asarray(flag, dtype=np.uint8), float(min_range_m), float(max_range_m),
    )  # fmt: skip
    if not valid:
        return None
    heading = heading[usable]
    return Beams(
        origin_xy=np.ascontiguousarray(origin_xy[usable], dtype=np.float64),
        heading_rad=heading,
        seen_m=seen[usable],
        hit=hit[usable],
        cos_h=np.cos(heading),
        sin_h=np.sin(heading),
    )


@dataclass(frozen=True)
class PointView:
    """Expected visibility of tracks: ``visible`` and ``occluded`` (k,) bool."""

    visible: NDArray[np.bool_]
    occluded: NDArray[np.bool_]


def point_visibility(
    beams: Beams | None,
    points: FloatArray,
    radius_m: FloatArray,
    footprint_m: FloatArray,
    sigma_m: FloatArray,
    min_beams: NDArray[np.int64],
    two_sided: NDArray[np.bool_],
    min_range_m: float,
    max_range_m: float,
    margin_m: float = 0.05,
) -> PointView:
    """Which points (k, 2) in ``base_link`` the scan should have seen (module docstring).

    A beam counts for a point when it passes within ``footprint_m`` (k,) of it, ahead of its
    origin (the cylinder's radius; for a corner the stretch of its two faces the extractor
    needs), the point's near surface (``radius_m`` (k,) nearer: a cylinder's radius, 0 for
    a corner) is in range, and the beam is clear to within ``3·sigma_m + margin_m`` of that
    surface (``sigma_m`` (k,): the track's position σ). Visible with ``min_beams`` (k,)
    such beams, or that many on each side of the point where ``two_sided`` (k,) (a corner's
    two faces); occluded when not visible and some beam in the footprint stopped short.
    """
    k = points.shape[0]
    if beams is None or k == 0 or beams.count == 0:
        return PointView(np.zeros(k, dtype=bool), np.zeros(k, dtype=bool))
    visible, occluded = visibility_kernels.point_visibility(
        np.ascontiguousarray(points, dtype=np.float64), np.asarray(radius_m, dtype=np.float64),
        np.asarray(footprint_m, dtype=np.float64), np.asarray(sigma_m, dtype=np.float64),
        np.asarray(min_beams, dtype=np.int64), np.asarray(two_sided, dtype=np.bool_),
        beams.origin_xy, beams.cos_h, beams.sin_h, beams.seen_m, float(min_range_m),
        float(max_range_m), float(margin_m),
    )  # fmt: skip
    return PointView(visible, occluded)


def segment_visibility(
    beams: Beams | None,
    alpha_rad: FloatArray,
    rho_m: FloatArray,
    lo_m: FloatArray,
    hi_m: FloatArray,
    sigma_m: FloatArray,
    min_beams: int,
    min_range_m: float,
    max_range_m: float,
    margin_m: float = 0.05,
    max_incidence_rad: float = 1.3,
) -> PointView:
    """Which segments the scan should have seen, in ``base_link``.

    A segment is the line ``x·cos α + y·sin α = ρ`` between along-line coordinates ``lo_m``
    and ``hi_m`` (along ``(−sin α, cos α)`` from the foot point ``ρ·(cos α, sin α)``). A beam
    sees it where it crosses the line within the extent, in range, at an incidence under
    ``max_incidence_rad`` (75°: more oblique, the extractor's fit fails), and measured no
    nearer than the crossing less ``3σ + margin_m``. Visible with at least ``min_beams`` such
    beams (the extractor's fewest points for a segment).
    """
    k = alpha_rad.size
    if beams is None or k == 0 or beams.count == 0:
        return PointView(np.zeros(k, dtype=bool), np.zeros(k, dtype=bool))
    visible, occluded = visibility_kernels.segment_visibility(
        np.asarray(alpha_rad, dtype=np.float64), np.asarray(rho_m, dtype=np.float64),
        np.asarray(lo_m, dtype=np.float64), np.asarray(hi_m, dtype=np.float64),
        np.asarray(sigma_m, dtype=np.float64), int(min_beams), beams.origin_xy, beams.cos_h,
        beams.sin_h, beams.seen_m, float(min_range_m), float(max_range_m), float(margin_m),
        math.cos(max_incidence_rad),
    )  # fmt: skip
    return PointView(visible, occluded)


def segment_ends_seen(
    endpoints: FloatArray,
    alpha_rad: FloatArray,
    rho_m: FloatArray,
    points_xy: FloatArray,
    origin_xy: FloatArray,
    range_m: FloatArray,
    flag: NDArray[np.uint8],
    max_range_m: float,
    margin_m: float = 0.05,
    skip: int = 3,
) -> NDArray[np.bool_]:
    """(k, 2) bool: whether each reported segment's first and last end is a real end.

    ``endpoints`` (k, 2, 2) are the segments' first and last samples projected on their lines
    (``base_link``), in sample order. The sample nearest each end is found among the scan's
    valid samples; then the first beam beyond it (further in sample order, passing over up to
    ``skip`` mixed, isolated or low-signal samples, which say nothing) decides:

    * none (the window ends there): not seen, the sensor only stopped looking;
    * a valid sample nearer than where the line would cross that beam (less a margin): the
      surface may go on behind the occluder, not seen;
    * any other valid sample (farther, or a different surface at about the line's distance,
      as at a corner): seen, the surface stops;
    * nothing in range (no reading, beyond the far limit): seen if the line would cross that
      beam within range (the sensor would have measured it), else not (the wall may go on
      beyond the depth of field).
    """
    k = endpoints.shape[0]
    if k == 0:
        return np.zeros((0, 2), dtype=bool)
    return visibility_kernels.segment_ends_seen(
        np.ascontiguousarray(endpoints, dtype=np.float64),
        np.ascontiguousarray(alpha_rad, dtype=np.float64),
        np.ascontiguousarray(rho_m, dtype=np.float64),
        np.ascontiguousarray(points_xy, dtype=np.float64),
        np.ascontiguousarray(origin_xy, dtype=np.float64),
        np.ascontiguousarray(range_m, dtype=np.float64),
        np.ascontiguousarray(flag, dtype=np.uint8),
        float(max_range_m),
        float(margin_m),
        int(skip),
    )
