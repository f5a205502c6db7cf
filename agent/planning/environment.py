"""The environment vector's obstacles, and whether the agent can vouch for the vector.

:func:`obstacles_from_tracks` selects and converts tracks (``odom``) to obstacles;
:func:`sensor_health` says whether the inputs are fresh and the head is working. The free
space beside them is :mod:`agent.planning.free_space`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from agent.arrays import FloatArray, largest_sigma

SEGMENT, CORNER, EDGE, CYLINDER, DOCKING = 0, 1, 2, 3, 4
CONFIRMED, COASTING = 1, 2

DOCKING_REFLECTIVITY = 2.5
"""Reflectivity (relative to off-white cardboard) from which a segment is a docking target.

Walls and boxes in the project's worlds lie between 0.3 and 2.0 (random worlds draw them
from that interval; the office's brightest, a metal cabinet, is 1.4); the docking plates are
retro-reflective, 3.0 in ``worlds/office.toml`` and about 5 and more for retro-reflective
tape seen near its axis. 2.5 sits 25 % above the brightest wall, beyond the few-percent
scatter of a tracked segment's reflectivity (a median over hundreds of samples), and below
the dimmest plate.
"""


@dataclass(frozen=True, eq=False)
class Obstacles:
    """Obstacles as a struct of arrays over ``k`` (frame ``odom``), as ``environment/1``
    carries them: ``obstacle_id`` (k,), ``kind`` (k,) 0-4, ``position_xy`` (k, 2) m,
    ``velocity_xy`` (k, 2) m/s, ``covariance`` (k, 4, 4) over x, y, vx, vy, ``extent``
    (k, 4) m, ``reflectivity`` (k,) (NaN if unknown), ``across_sigma_m`` (k,) m, or empty
    when the tracks' line parameters were not given (:func:`across_sigma`); ``last_seen_ns``
    (k,) the stamp of the scan that last updated each track, or empty when not given."""

    obstacle_id: NDArray[np.int64]
    kind: NDArray[np.uint8]
    position_xy: FloatArray
    velocity_xy: FloatArray
    covariance: FloatArray
    extent: FloatArray
    reflectivity: FloatArray
    across_sigma_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    last_seen_ns: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    @classmethod
    def empty(cls) -> Obstacles:
        return cls(
            obstacle_id=np.zeros(0, dtype=np.int64), kind=np.zeros(0, dtype=np.uint8),
            position_xy=np.zeros((0, 2)), velocity_xy=np.zeros((0, 2)),
            covariance=np.zeros((0, 4, 4)), extent=np.zeros((0, 4)), reflectivity=np.zeros(0),
        )  # fmt: skip

    def __len__(self) -> int:
        return int(self.obstacle_id.size)


@dataclass(frozen=True)
class ObstacleCounts:
    """What :func:`obstacles_from_tracks` did with the tracks it was given."""

    tentative: int = 0  # not yet confirmed: not obstacles
    non_finite: int = 0  # confirmed, but a state, covariance or extent not finite: dropped
    docking: int = 0  # segments reported as docking targets


def obstacles_from_tracks(
    track_id: NDArray[np.int64],
    kind: NDArray[np.uint8],
    status: NDArray[np.uint8],
    state: FloatArray,
    covariance: FloatArray,
    extent: FloatArray,
    reflectivity: FloatArray,
    docking_reflectivity: float = DOCKING_REFLECTIVITY,
    params: FloatArray | None = None,
    params_covariance: FloatArray | None = None,
    last_seen_ns: NDArray[np.int64] | None = None,
) -> tuple[Obstacles, ObstacleCounts]:
    """Obstacles from tracks (``tracks/2`` arrays, ``odom``).

    Confirmed (1) and coasting (2) tracks are obstacles, tentative ones (0) are not: a
    tentative track may be a phantom, and a coasting one is an object the tracker still
    believes in while it is out of view. ``obstacle_id`` is the track id (stable for the
    track's life). A segment whose reflectivity is at least ``docking_reflectivity`` is a
    docking target (kind 4), extent its end points; NaN reflectivity never is. Tracks with a
    non-finite state, covariance or extent are dropped and counted (the message needs them
    finite). Extent is kept as tracked for segments and cylinders, zeros for other kinds.
    With the tracks' ``params`` (k, 3) and ``params_covariance`` (k, 3, 3), each obstacle's
    ``across_sigma_m`` (:func:`across_sigma`); without them, empty. ``last_seen_ns`` (k,)
    is kept for the obstacles (empty without it).
    """
    confirmed = (status == CONFIRMED) | (status == COASTING)
    finite = (
        np.isfinite(state).all(axis=1)
        & np.isfinite(covariance).all(axis=(1, 2))
        & np.isfinite(extent).all(axis=1)
    )
    keep = confirmed & finite
    kinds = kind[keep].astype(np.uint8)
    refl = np.asarray(reflectivity[keep], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        docking = (kinds == SEGMENT) & (refl >= docking_reflectivity)
    kinds = np.where(docking, np.uint8(DOCKING), kinds).astype(np.uint8)
    # Three comparisons rather than np.isin (which costs some 60 µs on a handful of kinds).
    extended = (kinds == SEGMENT) | (kinds == CYLINDER) | (kinds == DOCKING)
    ext = np.where(extended[:, None], extent[keep], 0.0).astype(np.float64)
    obstacles = Obstacles(
        obstacle_id=track_id[keep].astype(np.int64),
        kind=kinds,
        position_xy=np.ascontiguousarray(state[keep, :2], dtype=np.float64),
        velocity_xy=np.ascontiguousarray(state[keep, 2:4], dtype=np.float64),
        covariance=np.ascontiguousarray(covariance[keep], dtype=np.float64),
        extent=ext,
        reflectivity=np.where(refl >= 0, refl, np.nan),
        across_sigma_m=(
            np.zeros(0)
            if params is None or params_covariance is None
            else across_sigma(
                kinds, ext, params[keep], params_covariance[keep], covariance[keep, :2, :2]
            )
        ),
        last_seen_ns=(
            np.zeros(0, np.int64)
            if last_seen_ns is None
            else np.asarray(last_seen_ns, dtype=np.int64)[keep]
        ),
    )
    counts = ObstacleCounts(
        tentative=int(np.count_nonzero(~confirmed)),
        non_finite=int(np.count_nonzero(confirmed & ~finite)),
        docking=int(np.count_nonzero(docking)),
    )
    return obstacles, counts


def across_sigma(
    kind: NDArray[np.uint8],
    extent: FloatArray,
    params: FloatArray,
    params_covariance: FloatArray,
    position_covariance: FloatArray,
) -> FloatArray:
    """Per obstacle (k,), how far (1σ, m) a segment's surface may lie across its line: the
    largest over its two end points ``p`` of

        σ_n(p)² = P_ρρ − 2·s·P_αρ + s²·P_αα,    s = p · (−sin α, cos α)

    the variance of the line ``x·cos α + y·sin α = ρ``'s signed distance from ``p`` under
    the (α, ρ) covariance ``P`` (to first order; a point's offset is linear in s, so the
    largest is at an end). For a docking target too; 0 for the other kinds, whose
    position covariance already says where they may be. Where the line's parameters are not
    finite, the larger σ of the reference point's ``position_covariance`` (k, 2, 2) (which
    holds the across-line one), as a reader without this field would take; at most 100 m.
    """
    segment = (kind == SEGMENT) | (kind == DOCKING)
    alpha = params[:, 0]
    normal_slope = np.stack([-np.sin(alpha), np.cos(alpha)], axis=1)
    p_aa = params_covariance[:, 0, 0]
    p_ar = 0.5 * (params_covariance[:, 0, 1] + params_covariance[:, 1, 0])
    p_rr = params_covariance[:, 1, 1]
    # Absurd inputs (a malformed message's 1e300 m ends) overflow to inf or NaN, which the
    # fallback and the 100 m bound below take care of: no warning for them.
    with np.errstate(over="ignore", invalid="ignore"):
        worst = np.zeros(kind.size)
        for end in (extent[:, 0:2], extent[:, 2:4]):
            s = np.einsum("kd,kd->k", end, normal_slope)
            worst = np.maximum(worst, p_rr - 2.0 * s * p_ar + s * s * p_aa)
        sigma = np.sqrt(np.maximum(worst, 0.0))
        sigma = np.where(np.isfinite(sigma), sigma, largest_sigma(position_covariance))
    # At most 100 m (``environment/1``'s range): beyond a few metres it says "anywhere", and
    # a consumer caps what it inflates by long before.
    return np.asarray(np.where(segment, np.minimum(sigma, 100.0), 0.0), dtype=np.float64)


@dataclass(frozen=True)
class HeadReport:
    """What the latest ``head_state`` says about the head's health."""

    stamp_s: float
    mode: str  # scanning, slewing, idle, fault
    laser_on: bool
    command_accepted: bool


def sensor_health(
    at_s: float,
    stale_after_s: float,
    tracks_s: float | None,
    scan_s: float | None,
    vehicle_s: float | None,
    head: HeadReport | None,
) -> list[str]:
    """Reasons the agent cannot vouch for a vector stamped ``at_s``; empty when it can.

    Each input's newest stamp (s; ``None`` if none has come) must be no older than
    ``stale_after_s`` before ``at_s``: ``stale_tracks``, ``stale_scans``, ``stale_vehicle``,
    ``stale_head``. The head must be scanning with its laser on and have taken the last
    command: ``head_fault`` (mode fault), ``laser_off`` (idle or laser off while it should
    scan), ``command_refused``.
    """
    reasons = []
    for name, stamp in (
        ("tracks", tracks_s),
        ("scans", scan_s),
        ("vehicle", vehicle_s),
        ("head", None if head is None else head.stamp_s),
    ):
        if stamp is None or not math.isfinite(stamp) or at_s - stamp > stale_after_s:
            reasons.append(f"stale_{name}")
    if head is not None:
        if head.mode == "fault":
            reasons.append("head_fault")
        elif not head.laser_on or head.mode == "idle":
            reasons.append("laser_off")
        if not head.command_accepted:
            reasons.append("command_refused")
    return reasons
